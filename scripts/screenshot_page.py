"""Screenshot of the web page for the README (docs/page.png), taken in headless Chromium.

    .venv/bin/python scripts/screenshot_page.py                 # starts itnet serve itself
    .venv/bin/python scripts/screenshot_page.py --url http://localhost:8000 --out /tmp/page.png
    .venv/bin/python scripts/screenshot_page.py --page '/?tab=scene&run=1' --out docs/scene.png

Also the one place that knows how to start the browser: ``open_browser`` (Debian's chromium
driven by Playwright), used by tests/web/.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
# Headless, no sandbox (root in a container), nothing that calls home. WebGL runs on SwiftShader
# (software), which Chromium only allows when asked for.
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]  # fmt: skip
PAGE = "/?example=chair_a&model=chair&budget_ms=50&play_ms=0&run=1"


def find_chromium() -> str | None:
    """The chromium executable (Debian's package installs /usr/bin/chromium), or None."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


@contextmanager
def open_browser(viewport: tuple[int, int] = (1400, 800)) -> Iterator[Any]:
    """A Playwright page in headless Chromium, with a fresh profile. Raises RuntimeError when
    Playwright or chromium is missing."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as err:
        raise RuntimeError(
            f"Playwright is not installed ({err}): pip install 'itnet[dev]'"
        ) from None
    executable = find_chromium()
    if executable is None:
        raise RuntimeError("no chromium found: apt-get install chromium")
    with ExitStack() as stack, sync_playwright() as playwright:
        profile = stack.enter_context(tempfile.TemporaryDirectory(prefix="itnet-chromium-"))
        context = playwright.chromium.launch_persistent_context(
            profile, executable_path=executable, args=CHROMIUM_ARGS, headless=True,
            viewport={"width": viewport[0], "height": viewport[1]},
        )  # fmt: skip
        try:
            yield context.pages[0] if context.pages else context.new_page()
        finally:
            context.close()


def screenshot(url: str, out: Path, page_path: str = PAGE) -> None:
    """Open the page at ``page_path`` (an example that runs as it loads), wait for the result,
    save a PNG."""
    with open_browser() as page:
        for _ in range(2):  # the first run warms a fresh server up; the second is the picture
            page.goto(url.rstrip("/") + page_path)
            page.wait_for_function("document.body.dataset.run === 'done'", timeout=30_000)
        page.wait_for_timeout(500)  # let the view draw its last frame
        page.screenshot(path=str(out))
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", help="a running itnet serve (default: start one here)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "page.png")
    parser.add_argument("--page", default=PAGE, help=f"the page's path and query (default {PAGE})")
    args = parser.parse_args()
    if args.url:
        screenshot(args.url, args.out, args.page)
        return
    sys.path.insert(0, str(ROOT))
    from benchmarks.harness import serve
    from itnet.pose.runtime import default_model_dir

    with (
        tempfile.TemporaryDirectory() as folder,
        serve(default_model_dir(), Path(folder) / "serve.log") as server,
    ):
        screenshot(server.url, args.out, args.page)


if __name__ == "__main__":
    main()
