"""The scene tab in a real browser (headless Chromium) against a live ``itnet serve``: a dropped
depth image gives the objects the API gives, drawn over the scene."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from benchmarks.harness import Server, serve
from itnet.model.scenes import Scene
from itnet.pose.runtime import default_model_dir
from itnet.scene.depth_io import depth_to_png

pytestmark = [pytest.mark.e2e, pytest.mark.slow]
DONE = "['done', 'failed'].includes(document.body.dataset.run)"


@pytest.fixture(scope="module")
def live_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    log = tmp_path_factory.mktemp("scene-web") / "serve.log"
    with serve(default_model_dir(), log, timeout_s=60) as running:
        yield running


@pytest.fixture(scope="module")
def page() -> Iterator[Any]:
    pytest.importorskip("playwright", reason="Playwright is not installed (pip install itnet[dev])")
    from scripts.screenshot_page import find_chromium, open_browser

    if find_chromium() is None:
        pytest.skip("no chromium on this machine (apt-get install chromium)")
    with open_browser() as opened:
        yield opened


def test_a_dropped_depth_image_shows_the_apis_objects(
    live_server: Server, page: Any, chair_scene: Scene, tmp_path: Path
) -> None:
    png = tmp_path / "chair.png"
    png.write_bytes(depth_to_png(np.round(chair_scene.depth * 1000).astype(np.uint16)))
    i = chair_scene.intrinsics
    camera = f"{i.fx},{i.fy},{i.cx},{i.cy}"
    errors: list[str] = []
    page.on("pageerror", lambda err: errors.append(str(err)))
    page.goto(f"{live_server.url}/?tab=scene&budget_ms=2000")
    page.wait_for_function("document.body.dataset.ready === 'true'")
    page.set_input_files("#file-scene", str(png))
    page.fill("#intrinsics", camera)
    page.click("#run")
    page.wait_for_function(DONE, timeout=30_000)
    assert page.evaluate("document.body.dataset.run") == "done", page.text_content("#status")
    shown = json.loads(page.text_content("#result"))
    query = dict(zip(["fx", "fy", "cx", "cy"], camera.split(","), strict=True))
    api = httpx.post(f"{live_server.url}/v1/scene", params={**query, "budget_ms": 2000},
                     content=png.read_bytes(), headers={"content-type": "image/png"},
                     timeout=30).json()  # fmt: skip
    assert [o["category"] for o in shown["objects"]] == [o["category"] for o in api["objects"]]
    assert len(shown["objects"]) == 1
    assert page.locator("#scene-objects li").count() == 1
    assert not errors
    # the drawn scene: its points, one box, and the object's axes where it has a pose
    drawn = page.evaluate("document.querySelectorAll('canvas#view3d').length")
    assert drawn == 1
