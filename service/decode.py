"""Request bytes -> (cloud, parameters). The two wire formats of one request:

* ``application/json``: an :class:`EstimateRequest` (points as ``[[x, y, z], ...]``);
* ``application/octet-stream``: the cloud as little-endian float32, N x 3 row-major (12 bytes a
  point), with ``budget_ms``, ``max_iterations`` and ``model`` in the query string.

Both raise :class:`ServiceError` (400/415/422) saying what is wrong. CPU-bound for large bodies:
call from a worker thread. :class:`Decoder` adds what a server needs on top: a JSON body that
holds more point arrays than ``max_points`` is refused from a count of its brackets (one pass of
``bytes.count``, about 6 ms for 16 MB) before it is parsed, and large JSON bodies are parsed in
a worker process, one at a time (in-process, pydantic holds the GIL for the whole parse: about
0.3 s for 250,000 points, during which every other request of the process would wait).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from itnet.pose.catalog import shorten
from itnet.pose.request import PoseRequest
from itnet.service.errors import ServiceError, describe_errors, malformed_json
from itnet.service.guards.parse_pool import ParsePool
from itnet.service.schemas import EstimateRequest

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


def decode_binary(body: bytes, query: Mapping[str, str]) -> tuple[NDArray[np.float32], PoseRequest]:
    """A float32 body and its query parameters -> cloud (N, 3) float32 and the parameters."""
    try:
        params = PoseRequest.from_query(query)
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
) -> tuple[NDArray[np.floating], PoseRequest]:
    """Dispatch on the Content-Type; anything but JSON or octet-stream is a 415."""
    kind = media_type(content_type)
    if is_json(content_type):
        no_query_beside_json(query)
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


def no_query_beside_json(query: Mapping[str, str]) -> None:
    """Parameters in the query string of a JSON request are a mistake, not something to ignore."""
    if query:
        names = ", ".join(shorten(name, 32) for name in list(query)[:3])
        raise ServiceError(
            422,
            "invalid_request",
            f"query parameters ({names}) are read only with a binary body: put them in the "
            "JSON body",
        )


def is_json(content_type: str | None) -> bool:
    kind = media_type(content_type)
    return kind in JSON_TYPES or kind.endswith("+json")


def count_points(body: bytes | str, max_points: int) -> None:
    """Refuse a body with more point arrays than ``max_points`` before parsing it: every point
    is one ``[``, plus the list's own. Counting is ~50x cheaper than parsing."""
    arrays = (body.count(b"[") if isinstance(body, bytes) else body.count("[")) - 1
    if arrays > max_points:
        raise ServiceError(
            422,
            "bad_cloud",
            f"too many points: the body holds {arrays} arrays, the maximum is "
            f"{max_points} points (refused before parsing)",
        )


class Decoder:
    """Decoding under a server's limits: the point count bounded before parsing; JSON bodies of
    ``heavy_bytes`` or more parsed in a worker process (``service/guards/parse_pool.py``), ``lanes`` at
    a time (a request that finds them taken gets a 503 at once)."""

    def __init__(
        self,
        max_points: int,
        heavy_bytes: int,
        lanes: int,
        retry_after_s: int,
        pool: ParsePool | None = None,
    ) -> None:
        self.max_points, self.heavy_bytes, self.retry_after_s = (
            max_points,
            heavy_bytes,
            retry_after_s,
        )
        self._lanes = threading.BoundedSemaphore(lanes)
        self.pool = pool or ParsePool(workers=lanes)
        self.json_ms_per_kb = _json_ms_per_kb()

    def expected_ms(self, body: bytes, content_type: str | None) -> float:
        """What decoding ``body`` costs on this machine when it is idle: a JSON body's size at
        the rate measured at start-up (a float32 body: none worth counting). A request refused
        because its decoding alone passed its budget (``AnytimeRun.check_served``) is refused
        for its body, never for a busy or cold moment of the server: the route passes the
        lesser of this and the measured time."""
        return len(body) / 1024 * self.json_ms_per_kb if is_json(content_type) else 0.0

    def http(
        self, body: bytes, content_type: str | None, query: Mapping[str, str]
    ) -> tuple[NDArray[np.floating], PoseRequest]:
        if not is_json(content_type) or len(body) < self.heavy_bytes:
            if is_json(content_type):
                count_points(body, self.max_points)
            return decode_http(body, content_type, query)
        no_query_beside_json(query)
        return self.json(body)

    def json(
        self, body: bytes | str, schema: type[EstimateRequest] = EstimateRequest
    ) -> tuple[NDArray[np.float64], EstimateRequest]:
        if len(body) < self.heavy_bytes:
            count_points(body, self.max_points)
            return decode_json(body, schema)
        with self.lane():
            return self.pool.parse(body, schema, self.max_points)

    def close(self) -> None:
        self.pool.close()

    @contextmanager
    def lane(self) -> Iterator[None]:
        """One of the ``lanes`` large parses, or the 503 that says they are all taken."""
        if not self._lanes.acquire(blocking=False):
            raise ServiceError(
                503,
                "overloaded",
                f"another large JSON body is being parsed; retry in {self.retry_after_s} s, or "
                "send the cloud as binary (application/octet-stream, 12 bytes a point)",
                headers={"Retry-After": str(self.retry_after_s)},
            )
        try:
            yield
        finally:
            self._lanes.release()


def _json_ms_per_kb(points: int = 2048, tries: int = 3) -> float:
    """This machine's JSON decoding rate, ms per KiB: the quickest of ``tries`` decodes of a
    cloud of ``points`` points (a few ms, once per process), in the thread's CPU time: a server
    started on a loaded machine (its process descheduled for seconds) measures the rate an idle
    one has."""
    cloud = np.round(np.random.default_rng(0).normal(size=(points, 3)), 6).tolist()
    body = json.dumps({"points": cloud, "budget_ms": 50}).encode()
    best = float("inf")
    for _ in range(tries):
        start = time.thread_time()
        decode_json(body, EstimateRequest)
        best = min(best, (time.thread_time() - start) * 1e3)
    return best / (len(body) / 1024)


def _non_empty(points: NDArray) -> NDArray:
    if len(points) == 0:
        raise ServiceError(422, "bad_cloud", "the cloud is empty: no points were sent")
    return points
