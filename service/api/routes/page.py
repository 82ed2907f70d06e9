"""``GET /``: the web page that shows the anytime refinement live; ``/static``: its files.

The page is plain HTML, CSS and ES modules shipped inside the package (``service/static``), with
three.js vendored in ``static/vendor`` (MIT, its LICENSE beside it): no build step, no internet.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

router = APIRouter(tags=["page"])


def static_dir() -> Path:
    """The page's files, inside the installed package."""
    return Path(str(resources.files("itnet.service") / "static"))


def static_files() -> StaticFiles:
    """The ASGI app that serves ``static_dir()`` (mounted at ``/static``)."""
    return StaticFiles(directory=static_dir())


@router.get("/", include_in_schema=False)
async def page() -> FileResponse:
    """The page. Its state lives in the URL: ``/?example=chair_a&model=chair&budget_ms=50&run=1``
    opens the example and runs it (see docs/page.md)."""
    return FileResponse(static_dir() / "index.html", media_type="text/html")
