"""Request bytes -> (cloud, parameters). The two wire formats of one request:

* ``application/json``: an :class:`EstimateRequest` (points as ``[[x, y, z], ...]``);
* ``application/octet-stream``: the cloud as little-endian float32, N x 3 row-major (12 bytes a
  point), with ``budget_ms``, ``max_iterations`` and ``model`` in the query string.

Both raise :class:`ServiceError` (400/415/422) saying what is wrong. CPU-bound for large bodies:
call from a worker thread.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from itnet.service.errors import ServiceError, describe_errors, malformed_json
from itnet.service.schemas import EstimateParams, EstimateRequest

JSON_TYPES = ("application/json",)
BINARY_TYPES = ("application/octet-stream",)
POINT_BYTES = 12  # three float32


def media_type(content_type: str | None) -> str:
    """``'application/json; charset=utf-8'`` -> ``'application/json'``."""
    return (content_type or "").split(";", 1)[0].strip().lower()


def decode_json(
    body: bytes | str, schema: type[EstimateRequest] = EstimateRequest
) -> tuple[NDArray[np.float64], EstimateRequest]:
    """A JSON request -> cloud (N, 3) float64 and the parsed request."""
    if not body or not body.strip():
        raise malformed_json("the body is empty (expected an object with 'points')")
    try:
        request = schema.model_validate_json(body)
    except ValidationError as err:
        errors = err.errors(include_input=False, include_url=False)
        if errors and errors[0]["type"] == "json_invalid":
            raise malformed_json(str(errors[0]["msg"]).removeprefix("Invalid JSON: ")) from None
        if errors and errors[0]["type"] == "model_type":
            raise ServiceError(
                422, "invalid_request", "the request must be a JSON object"
            ) from None
        raise ServiceError(422, "invalid_request", describe_errors(errors)) from None
    points = np.asarray(request.points, dtype=np.float64).reshape(-1, 3)
    return _non_empty(points), request


def decode_binary(
    body: bytes, query: Mapping[str, str]
) -> tuple[NDArray[np.float32], EstimateParams]:
    """A float32 body and its query parameters -> cloud (N, 3) float32 and the parameters."""
    try:
        params = EstimateParams.model_validate(dict(query))
    except ValidationError as err:
        errors = err.errors(include_input=False, include_url=False)
        raise ServiceError(422, "invalid_request", describe_errors(errors)) from None
    if len(body) % POINT_BYTES:
        raise ServiceError(
            400,
            "truncated_binary",
            f"truncated binary cloud: {len(body)} bytes is not a multiple of {POINT_BYTES} "
            "(little-endian float32 x, y, z per point)",
        )
    points = np.frombuffer(body, dtype="<f4").reshape(-1, 3)
    return _non_empty(points), params


def decode_http(
    body: bytes, content_type: str | None, query: Mapping[str, str]
) -> tuple[NDArray[np.floating], EstimateParams]:
    """Dispatch on the Content-Type; anything but JSON or octet-stream is a 415."""
    kind = media_type(content_type)
    if kind in JSON_TYPES or kind.endswith("+json"):
        return decode_json(body)
    if kind in BINARY_TYPES:
        return decode_binary(body, query)
    problem = f"unsupported Content-Type {content_type!r}" if content_type else "no Content-Type"
    raise ServiceError(
        415,
        "unsupported_media_type",
        f"{problem}: send application/json or application/octet-stream "
        "(little-endian float32 N x 3)",
    )


def _non_empty(points: NDArray) -> NDArray:
    if len(points) == 0:
        raise ServiceError(422, "bad_cloud", "the cloud is empty: no points were sent")
    return points
