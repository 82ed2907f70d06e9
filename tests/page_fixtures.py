"""Fixtures of the page tests (tests/web, tests/scene): a real ``itnet serve`` with the shipped
models, and a page in headless Chromium."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from benchmarks.harness import Server, serve
from itnet.pose.runtime import default_model_dir
from scripts.screenshot_page import find_chromium, open_browser


@pytest.fixture(scope="module")
def live_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """``itnet serve`` on a free port with the models shipped in the package."""
    log = tmp_path_factory.mktemp("web") / "serve.log"
    with serve(default_model_dir(), log, timeout_s=60) as running:
        yield running


@pytest.fixture(scope="module")
def browser_page() -> Iterator[Any]:
    """A page in headless Chromium; skips only where no browser is installed."""
    pytest.importorskip("playwright", reason="Playwright is not installed (pip install itnet[dev])")
    if find_chromium() is None:
        pytest.skip(
            "no chromium on this machine (apt-get install chromium; .ci/run does it as root)"
        )
    with open_browser() as page:
        yield page
