"""``POST /v1/scene``: a depth image or a scene cloud in, every object's category and pose out.

Bodies, by ``Content-Type``:

* ``image/png``: a 16-bit greyscale depth image (depth units, millimetres unless
  ``depth_scale``), with the intrinsics ``fx``, ``fy``, ``cx``, ``cy`` in the query;
* ``application/x-npy``: a ``.npy`` array, a depth image (H, W) (float: metres; integers: depth
  units) with the intrinsics, or a cloud (N, 3);
* ``application/octet-stream``: a cloud, little-endian float32 N x 3;
* ``application/json``: ``{"points": [[x, y, z], ...]}`` (a cloud) and the query's fields.

Clouds are in the camera's frame (x right, y down, z ahead), metres. Bounded: the body by
``max_body_bytes``, a depth image by ``SceneLimits.max_pixels`` and a cloud by ``max_points``
(413), ``budget_ms`` by ``max_budget_ms``; the request holds one of the estimate slots. The
budget counts from the request's arrival (its upload and decoding included), as for poses.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Annotated, Any

import anyio
import numpy as np
from fastapi import APIRouter, Query, Request
from pydantic import ValidationError

from itnet.request_fields import query_parameters
from itnet.scene import (
    Intrinsics,
    SceneInputError,
    SceneTooLargeError,
    find_objects,
    from_array,
    from_cloud,
)
from itnet.scene.depth_io import read_npy
from itnet.scene.inputs import SceneInput, SceneLimits, from_png
from itnet.scene.posing import NoClassifierError
from itnet.scene.request import SceneRequest
from itnet.service.api.deps import ArrivedDep, BodyDep, GateOpenDep, StateDep
from itnet.service.errors import ServiceError, describe_errors, malformed_json
from itnet.service.schemas import ErrorResponse
from itnet.service.state import ServiceState

router = APIRouter(prefix="/v1", tags=["scene"])
LIMITS = SceneLimits()
MAX_SHOWN = 50_000  # scene points a reply may carry for drawing
ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorResponse, "description": "malformed JSON or truncated binary body"},
    413: {"model": ErrorResponse, "description": "body, image or cloud over its limit"},
    415: {"model": ErrorResponse, "description": "not PNG, .npy, octet-stream or JSON"},
    422: {
        "model": ErrorResponse,
        "description": "bad scene (no intrinsics, wrong bit depth, "
        "no valid depth, ...) or parameters",
    },
    503: {"model": ErrorResponse, "description": "not ready, or busy (see Retry-After)"},
}
ROUTE_PARAMETERS = ("fx", "fy", "cx", "cy", "indices", "points")  # the rest: SceneRequest's
OPENAPI_EXTRA = {
    "parameters": query_parameters(SceneRequest),
    "requestBody": {
        "required": True,
        "content": {
            "image/png": {"schema": {"type": "string", "format": "binary"}},
            "application/x-npy": {"schema": {"type": "string", "format": "binary"}},
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            "application/json": {
                "schema": {
                    "type": "object",
                    "required": ["points"],
                    "properties": {
                        "points": {
                            "type": "array",
                            "items": {
                                "type": "array",
                                "items": {"type": "number"},
                                "minItems": 3,
                                "maxItems": 3,
                            },
                        }
                    },
                }
            },
        },
    },
}
Focal = Annotated[float | None, Query(gt=0, description="focal length in pixels (depth images)")]
Centre = Annotated[float | None, Query(description="principal point in pixels (depth images)")]


@router.post(
    "/scene", responses=ERRORS, openapi_extra=OPENAPI_EXTRA,
    summary="Every object of a depth image or scene cloud: category, pose, box, points",
)  # fmt: skip
async def scene(
    request: Request,
    arrived: ArrivedDep,
    body: BodyDep,
    state: StateDep,
    _gate: GateOpenDep,
    fx: Focal = None,
    fy: Focal = None,
    cx: Centre = None,
    cy: Centre = None,
    indices: Annotated[bool, Query(description="each object's point indices")] = True,
    points: Annotated[
        int,
        Query(
            ge=0,
            le=MAX_SHOWN,
            description="also send this many of the scene's points, "
            "drawn at random, with the object each belongs to (for drawing; -1: none)",
        ),
    ] = 0,
) -> dict[str, Any]:
    """The reply is ``itnet scene --json``'s object: ``objects`` (each with ``category``,
    ``category_probability``, ``T_canonical_from_input`` or null, ``box``, ``points``,
    ``indices``), ``up``, ``floor``, ``walls`` and the times. The query's other fields are
    ``SceneRequest``'s."""
    asked = _scene_request(request.query_params, state.settings.limits.max_budget_ms)
    given = [v for v in (fx, fy, cx, cy) if v is not None]
    if given and len(given) != 4:
        raise ServiceError(422, "invalid_request", "give all four intrinsics: fx, fy, cx, cy")
    camera = Intrinsics(fx, fy, cx, cy) if fx and fy and cx is not None and cy is not None else None
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    with state.gate.slot():
        return await anyio.to_thread.run_sync(
            _find, state, body, kind, camera, asked, indices, points, arrived
        )


def _scene_request(query: Mapping[str, str], max_budget_ms: float) -> SceneRequest:
    """The query's ``SceneRequest`` fields (the route's own parameters left out) -> the request;
    a 422 saying what is wrong, or that the budget is over this service's limit."""
    fields = {k: v for k, v in query.items() if k not in ROUTE_PARAMETERS}
    try:
        asked = SceneRequest.from_query(fields)
    except ValidationError as err:
        errors = err.errors(include_input=False, include_url=False)
        raise ServiceError(422, "invalid_request", describe_errors(errors)) from None
    if asked.budget_ms > max_budget_ms:
        raise ServiceError(422, "invalid_request",
                           f"budget_ms {asked.budget_ms:g} is over the limit of {max_budget_ms:g} ms")  # fmt: skip
    return asked


def _decode(
    body: bytes, kind: str, camera: Intrinsics | None, depth_scale: float | None
) -> SceneInput:
    """The body -> the scene's points (SceneInputError, ServiceError 400/415)."""
    if kind == "image/png":
        return from_png(body, camera, depth_scale, LIMITS)
    if kind == "application/x-npy":
        return from_array(read_npy(body), camera, depth_scale, LIMITS)
    if kind == "application/octet-stream":
        if len(body) % 12:
            raise ServiceError(400, "truncated_body",
                               f"a float32 N x 3 body has a multiple of 12 bytes, got {len(body)}")  # fmt: skip
        return from_cloud(np.frombuffer(body, dtype="<f4").reshape(-1, 3), LIMITS)
    if kind == "application/json":
        try:
            points = json.loads(body)["points"]
            cloud = np.asarray(points, dtype=np.float64)
        except (ValueError, KeyError, TypeError) as err:
            raise malformed_json(f'expected {{"points": [[x, y, z], ...]}} ({err})') from None
        return from_cloud(cloud, LIMITS)
    raise ServiceError(
        415, "unsupported_media_type",
        "send image/png, application/x-npy, application/octet-stream or application/json",
    )  # fmt: skip


def _find(
    state: ServiceState, body: bytes, kind: str, camera: Intrinsics | None, asked: SceneRequest,
    indices: bool, shown: int = 0, arrived: float | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Decode and find the objects (CPU: a worker thread), the budget counted from the
    request's ``arrived`` (``time.perf_counter()``; default now)."""
    if not state.ready:
        raise ServiceError(503, "not_ready", f"no model is loaded: {state.load_error}")
    arguments = asked.arguments()
    try:
        given = _decode(body, kind, camera, arguments.pop("depth_scale"))
        result = find_objects(given, catalog=state.catalog, started=arrived, **arguments)
    except SceneTooLargeError as err:
        raise ServiceError(413, "too_large", str(err)) from None
    except SceneInputError as err:
        raise ServiceError(422, "bad_scene", str(err)) from None
    except NoClassifierError as err:
        raise ServiceError(422, "no_classifier", str(err)) from None
    reply = result.as_dict(indices)
    if shown:
        reply.update(_shown_points(given, [o.indices for o in result.objects], shown))
    return reply


def _shown_points(given: SceneInput, objects: list[np.ndarray], count: int) -> dict[str, Any]:
    """Up to ``count`` of the scene's points (random, in order), rounded to 0.1 mm, and the
    object each belongs to (its place in ``objects``, -1: none)."""
    owner = np.full(len(given.points), -1)
    for k, rows in enumerate(objects):
        owner[np.searchsorted(given.indices, rows)] = k
    rng = np.random.default_rng(0)
    chosen = np.sort(rng.choice(len(given.points), min(count, len(given.points)), replace=False))
    return {
        "scene_points": np.round(given.points[chosen], 4).tolist(),
        "scene_point_objects": owner[chosen].tolist(),
    }
