"""Clouds for the page: the shipped examples, and a dropped file read by ``itnet.cloud_io``.

* ``GET /v1/examples``: the example clouds (name, file, point count), the example pairs with
  their true ``T_b_from_a``, and the example scenes (name, file, the camera's intrinsics, the
  objects' categories);
* ``GET /v1/examples/{name}``: one example's points;
* ``GET /v1/examples/scenes/{name}``: one example scene's depth image (16-bit PNG, millimetres);
* ``POST /v1/clouds/read?filename=scan.ply``: the raw bytes of a .ply/.pcd/.xyz/.pts/.txt/.npy
  file -> its points, read by the same readers as the CLI (bounded by ``max_body_bytes`` and
  ``max_points``; a bad file is a 422 that says what is wrong).
"""

from __future__ import annotations

import json
import tempfile
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import anyio
from fastapi import APIRouter, Query, Response
from numpy.typing import NDArray

from itnet.cloud_io import SUFFIXES, CloudReadError, read_cloud
from itnet.pose.cloud import validate_cloud
from itnet.pose.errors import BadCloudError
from itnet.service.api.deps import BodyDep, StateDep
from itnet.service.errors import ServiceError
from itnet.service.schemas import ErrorResponse

router = APIRouter(prefix="/v1", tags=["clouds"])
ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorResponse, "description": "invalid Content-Length"},
    404: {"model": ErrorResponse, "description": "no such example"},
    408: {"model": ErrorResponse, "description": "the body did not arrive in time"},
    413: {"model": ErrorResponse, "description": "file over the body size limit"},
    422: {"model": ErrorResponse, "description": "unknown format, unreadable or bad cloud"},
    503: {"model": ErrorResponse, "description": "busy (see Retry-After)"},
}


def examples_dir() -> Path:
    """The example clouds shipped in the package."""
    return Path(str(resources.files("itnet") / "examples"))


@cache
def _catalogue() -> dict[str, Any]:
    """Every example cloud by name, and every pair (``<pair>_a``/``_b`` with ``<pair>_truth``)."""
    folder = examples_dir()
    clouds = {p.stem: p for p in sorted(folder.glob("*.ply"))}
    pairs = []
    for truth in sorted(folder.glob("*_truth.json")):
        pair = truth.name.removesuffix("_truth.json")
        if f"{pair}_a" in clouds and f"{pair}_b" in clouds:
            known = json.loads(truth.read_text())
            ups = {k: known[k] for k in ("up_a", "up_b") if k in known}  # each scan's up
            pairs.append({"name": pair, "a": f"{pair}_a", "b": f"{pair}_b",
                          "category": known.get("category"), "T_b_from_a": known["T_b_from_a"],
                          "source": known.get("source", ""), **ups})  # fmt: skip
    scenes = []
    for image in sorted(folder.glob("*.png")):  # NAME.png, NAME_camera.json, NAME_truth.json
        camera, truth = (folder / f"{image.stem}_{part}.json" for part in ("camera", "truth"))
        if camera.is_file() and truth.is_file():
            intrinsics = json.loads(camera.read_text())
            scenes.append({"name": image.stem, "file": image.name,
                           "intrinsics": {k: intrinsics[k] for k in ("fx", "fy", "cx", "cy")},
                           "categories": [o["category"] for o in
                                          json.loads(truth.read_text())["objects"]]})  # fmt: skip
    return {"clouds": clouds, "pairs": pairs, "scenes": scenes}


@cache
def _points(name: str) -> list[list[float]]:
    return read_cloud(_catalogue()["clouds"][name]).tolist()


@router.get("/examples", summary="The shipped example clouds and pairs")
async def examples() -> dict[str, Any]:
    catalogue = _catalogue()
    listed = [{"name": name, "file": path.name, "points": len(_points(name))}
              for name, path in catalogue["clouds"].items()]  # fmt: skip
    return {"examples": listed, "pairs": catalogue["pairs"], "scenes": catalogue["scenes"]}


@router.get(
    "/examples/scenes/{name}",
    responses={**ERRORS, 200: {"content": {"image/png": {}}}},
    response_class=Response,
    summary="One example scene's depth image",
)
async def example_scene(name: str) -> Response:
    """The depth image (16-bit greyscale PNG, millimetres) of an example scene of ``GET
    /v1/examples``; its intrinsics are listed there."""
    scenes = {s["name"]: s for s in _catalogue()["scenes"]}
    if name not in scenes:
        known = ", ".join(scenes)
        raise ServiceError(404, "not_found", f"no example scene named {name!r} (known: {known})")
    data = (examples_dir() / scenes[name]["file"]).read_bytes()
    return Response(data, media_type="image/png")


@router.get("/examples/{name}", responses=ERRORS, summary="One example cloud's points")
async def example(name: str) -> dict[str, Any]:
    if name not in _catalogue()["clouds"]:
        known = ", ".join(_catalogue()["clouds"])
        raise ServiceError(404, "not_found", f"no example named {name!r} (known: {known})")
    points = _points(name)
    return {"name": name, "count": len(points), "points": points}


@router.post("/clouds/read", responses=ERRORS, summary="Read a cloud file's points")
async def read_file(
    body: BodyDep,
    state: StateDep,
    filename: str = Query(..., max_length=255, description="the file's name (for its format)"),
) -> dict[str, Any]:
    """Send the file's bytes as the body (any Content-Type); get its points back, as the CLI
    would read them. Formats: .ply (ascii, binary), .pcd (ascii, binary, binary_compressed),
    .xyz, .pts, .txt, .npy."""
    suffix = Path(filename).suffix.lower()
    if suffix not in SUFFIXES:
        raise ServiceError(
            422,
            "bad_file",
            f"{filename}: unknown format {suffix or '(none)'!r} (known: {', '.join(SUFFIXES)})",
        )
    with state.gate.slot():  # parsing a large text file is CPU work: it counts as a request
        points = await anyio.to_thread.run_sync(_read, body, suffix, filename, state)
    return {"name": filename, "count": len(points), "points": points.tolist()}


def _read(body: bytes, suffix: str, filename: str, state: Any) -> NDArray:
    """The file's bytes -> validated (N, 3) points, through ``itnet.cloud_io.read_cloud``."""
    with tempfile.TemporaryDirectory(prefix="itnet-upload-") as folder:
        path = Path(folder) / f"upload{suffix}"
        path.write_bytes(body)
        try:
            points = read_cloud(path)
        except CloudReadError as err:
            raise ServiceError(422, "bad_file", str(err).replace(str(path), filename, 1)) from None
    try:
        return validate_cloud(points, state.settings.limits.engine_limits())
    except BadCloudError as err:
        raise ServiceError(422, "bad_cloud", f"{filename}: {err}") from None
