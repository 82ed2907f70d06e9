"""``POST /v1/align``: T_b_from_a (moves cloud A onto cloud B) with the service's loaded model.

The same alignment as ``itnet-align`` (``itnet.alignment.pipeline.align_clouds``: both clouds'
poses as ``POST /v1/estimate`` serves them, posed together; the composed pose, its rivals where
it is in doubt, the likeliest), run in-process on the models this server already holds; it is
what ``itnet-align --server`` asks for. The body is ``AlignRequest``'s fields and the two clouds.

Bounded like an estimate: the body by ``max_body_bytes``, each cloud by ``min_points`` and
``max_points``, ``budget_ms`` (the whole alignment's, counted from the request's arrival) by
``max_budget_ms``, ``max_iterations`` by its limit, and the request holds one of the
``max_concurrent_requests`` slots.
"""

from __future__ import annotations

from typing import Any

import anyio
from fastapi import APIRouter
from pydantic import Field, ValidationError

from itnet.alignment.request import AlignRequest
from itnet.pose.cloud import validate_cloud
from itnet.pose.errors import BadCloudError, PoseError
from itnet.service.api.deps import ArrivedDep, BodyDep, GateOpenDep, StateDep
from itnet.service.errors import ServiceError, describe_errors, malformed_json
from itnet.service.schemas import ErrorResponse, Point
from itnet.service.state import ServiceState

router = APIRouter(prefix="/v1", tags=["align"])
ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorResponse, "description": "malformed JSON"},
    408: {"model": ErrorResponse, "description": "the body did not arrive in time"},
    404: {"model": ErrorResponse, "description": "unknown model"},
    413: {"model": ErrorResponse, "description": "body over the size limit"},
    422: {"model": ErrorResponse, "description": "bad cloud or parameters"},
    503: {"model": ErrorResponse, "description": "not ready, or busy (see Retry-After)"},
}


class AlignBody(AlignRequest):
    """Two clouds of one object (or two objects of one category), in the same unit, and how to
    align them (``itnet.alignment.request.AlignRequest``)."""

    points_a: list[Point] = Field(fail_fast=True, description="cloud A (moved), N x 3")
    points_b: list[Point] = Field(fail_fast=True, description="cloud B (reference), M x 3")


@router.post(
    "/align",
    responses=ERRORS,
    summary="Align cloud A onto cloud B (T_b_from_a)",
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {
                    "schema": AlignBody.model_json_schema(
                        ref_template="#/components/schemas/{model}"
                    )
                }
            },
        }
    },
)
async def align(
    _gate: GateOpenDep, body: BodyDep, state: StateDep, arrived: ArrivedDep
) -> dict[str, Any]:
    """The reply is ``itnet-align --json``'s object: ``T_b_from_a`` (4x4, row-major, B's units),
    the chosen ``hypothesis`` and its ``probability``, the ``runner_up``, ``refined``, the
    hypotheses judged and both canonical poses, plus ``model`` and ``symmetry``. The budget
    counts from the request's arrival."""
    with state.gate.slot():  # (``_gate`` refused the request before its body if none was free)
        return await anyio.to_thread.run_sync(_align, state, body, arrived)


def _parse(body: bytes) -> AlignBody:
    if not body.strip():
        raise malformed_json("the body is empty (expected points_a and points_b)")
    try:
        return AlignBody.model_validate_json(body)
    except ValidationError as err:
        errors = err.errors(include_input=False, include_url=False)
        if errors and errors[0]["type"] == "json_invalid":
            raise malformed_json(str(errors[0]["msg"]).removeprefix("Invalid JSON: ")) from None
        raise ServiceError(422, "invalid_request", describe_errors(errors)) from None


def _align(state: ServiceState, body: bytes, arrived: float) -> dict[str, Any]:
    """Decode, check against the limits, align (CPU: runs in a worker thread)."""
    from itnet.alignment.estimators import in_process_estimator
    from itnet.alignment.pipeline import CloudEstimateError, align_clouds
    from itnet.alignment.refine import RefineUnavailable, refine_wanted

    request = _parse(body)
    model = state.model(request.model)
    limits = state.settings.limits
    if request.budget_ms > limits.max_budget_ms:
        raise ServiceError(422, "invalid_request",
                           f"budget_ms {request.budget_ms:g} is over the limit of "
                           f"{limits.max_budget_ms:g} ms")  # fmt: skip
    if request.max_iterations is not None and request.max_iterations > limits.max_iterations:
        raise ServiceError(422, "invalid_request",
                           f"max_iterations {request.max_iterations} is over the limit of "
                           f"{limits.max_iterations}")  # fmt: skip
    clouds = []
    for label, points in (("A", request.points_a), ("B", request.points_b)):
        try:
            clouds.append(validate_cloud(points, limits.engine_limits()))
        except BadCloudError as err:
            raise ServiceError(422, "bad_cloud", f"cloud {label}: {err}") from None
    try:
        refine = refine_wanted(request.refine)
    except RefineUnavailable as err:
        raise ServiceError(422, "refine_unavailable", str(err)) from None
    options = request.options(model.card, refine)
    estimate = in_process_estimator(state.catalog, request.pose_request(model.card.name), arrived)
    ups = {"up_a": request.up_a, "up_b": request.up_b}
    try:
        result = align_clouds(clouds[0], clouds[1], estimate, options, **ups, started=arrived)
    except ValueError as err:  # an up that is not a direction (the zero vector)
        raise ServiceError(422, "invalid_request", str(err)) from None
    except CloudEstimateError as err:
        cause = err.__cause__
        if isinstance(cause, PoseError):
            refused = ServiceError.of(cause)
            raise ServiceError(refused.status, refused.kind, f"cloud {err.cloud}: {cause}",
                               refused.headers) from None  # fmt: skip
        raise ServiceError(422, "bad_cloud", f"cloud {err.cloud}: {cause}") from None
    reply = {"model": model.card.name, "symmetry": options.symmetry, **result.to_dict()}
    return reply | {k: list(v) for k, v in ups.items() if v is not None}
