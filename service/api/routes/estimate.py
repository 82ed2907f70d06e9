"""``POST /v1/estimate``: one cloud in, the anytime estimate out (final pose + every iteration)."""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

import anyio
import pydantic_core
from fastapi import APIRouter, Request, Response

from itnet.pose.loop import AnytimeRun
from itnet.pose.reply import estimates_to_dicts
from itnet.pose.request import PoseRequest
from itnet.request_fields import query_parameters
from itnet.service.api.deps import ArrivedDep, BodyDep, GateOpenDep, StateDep
from itnet.service.errors import ServiceError
from itnet.service.schemas import EXAMPLE_REQUEST, ErrorResponse, EstimateRequest, EstimateResponse
from itnet.service.state import ServiceState

router = APIRouter(prefix="/v1", tags=["estimate"])

ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorResponse, "description": "malformed JSON or truncated binary body"},
    404: {"model": ErrorResponse, "description": "unknown model"},
    413: {"model": ErrorResponse, "description": "body over the size limit"},
    415: {"model": ErrorResponse, "description": "neither JSON nor octet-stream"},
    422: {"model": ErrorResponse, "description": "bad cloud or parameters"},
    503: {"model": ErrorResponse, "description": "not ready, or busy (see Retry-After)"},
}


OPENAPI_EXTRA = {
    "parameters": query_parameters(PoseRequest, "binary bodies only: "),
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {
                "schema": EstimateRequest.model_json_schema(
                    ref_template="#/components/schemas/{model}"
                ),
                "example": EXAMPLE_REQUEST,
            },
            "application/octet-stream": {
                "schema": {
                    "type": "string",
                    "format": "binary",
                    "description": (
                        "little-endian float32, N x 3 row-major (12 bytes a point); "
                        "parameters in the query string"
                    ),
                },
            },
        },
    },
}


@router.post(
    "/estimate",
    response_model=EstimateResponse,
    responses=ERRORS,
    openapi_extra=OPENAPI_EXTRA,
    summary="Estimate T_canonical_from_input of one cloud within a time budget",
)
async def estimate(
    request: Request, arrived: ArrivedDep, gate: GateOpenDep, body: BodyDep, state: StateDep
) -> Response:
    """Send the cloud as JSON, or as raw float32 (``Content-Type: application/octet-stream``)
    with the parameters in the query string. The reply is the final pose in the input's units,
    every per-iteration estimate, the iteration count and why the loop stopped (``budget``,
    ``max_iterations``, ``converged``). ``elapsed_ms`` counts from the request's arrival and
    stays within ``budget_ms`` up to scheduling noise. A client that disconnects stops the run."""
    content_type, query = request.headers.get("content-type"), dict(request.query_params)
    handle = _RunHandle()
    with state.gate.slot():  # (``gate`` refused the request before its body if none was free)
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(_watch_disconnect, request, handle)
            # Decoding, validation, every step and the reply's serialisation are CPU work: one
            # worker-thread hop (each hop waits for the GIL, which is costly under load).
            outcome = await anyio.to_thread.run_sync(
                _decode_and_run, state, body, content_type, query, arrived, handle
            )
            tasks.cancel_scope.cancel()
    if isinstance(outcome, Exception):
        raise outcome
    reply, loop_end, name, iterations, stopped_by = outcome
    now = time.perf_counter()
    # What the next runs keep in reserve: the time from the loop's end to here.
    state.handback.record((now - loop_end) * 1e3)
    state.metrics.observe_run(name, iterations, stopped_by)
    # elapsed_ms is stamped here, when the reply leaves the handler, not when the loop ended.
    elapsed = f'{{"elapsed_ms": {round((now - arrived) * 1e3, 3)}, '.encode()
    return Response(content=elapsed + reply[1:], media_type="application/json")


class _RunHandle:
    """One request's run and whether its client left (set from two threads, hence the lock)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._run: AnytimeRun | None = None
        self.client_left = False

    def attach(self, run: AnytimeRun) -> None:
        with self._lock:
            self._run = run
            if self.client_left:
                run.cancel()

    def client_gone(self) -> None:
        with self._lock:
            self.client_left = True
            if self._run is not None:
                self._run.cancel()


async def _watch_disconnect(request: Request, handle: _RunHandle) -> None:
    """Wait for the client to leave, then cancel its run: no step starts after that."""
    while (await request.receive())["type"] != "http.disconnect":
        pass
    handle.client_gone()


def _decode_and_run(
    state: ServiceState,
    body: bytes,
    content_type: str | None,
    query: Mapping[str, str],
    arrived: float,
    handle: _RunHandle,
) -> tuple[bytes, float, str, int, str] | Exception:
    """Decode, validate, run to the end and serialise the reply -> (JSON bytes, perf_counter at
    the loop's end, model, iterations, stop reason). The error is returned, not raised: an
    exception would leave the task group wrapped in an ExceptionGroup."""
    try:
        decoding = time.perf_counter()
        points, params = state.decoder.http(body, content_type, query)
        decode_ms = (time.perf_counter() - decoding) * 1e3
        # the body's own cost: a cold or busy moment of the server is not the body's
        decode_ms = min(decode_ms, state.decoder.expected_ms(body, content_type))
        run = state.start_run(points, params, arrived, state.handback.reserve_ms(), decode_ms)
    except Exception as err:
        return err
    handle.attach(run)
    try:
        with state.serving(run):
            estimates = list(run)
    except ServiceError as err:
        return err
    loop_end = time.perf_counter()
    stopped_by = "disconnected" if handle.client_left else str(run.stopped_by)
    reply = {**run.result(), "stopped_by": stopped_by,
             "estimates": estimates_to_dicts(estimates)}  # fmt: skip
    del reply["elapsed_ms"]  # stamped by the handler when the reply leaves (see estimate)
    # pydantic-core's serialiser: 0.03 ms for a reply that json.dumps took 0.28 ms for (2 cores)
    return pydantic_core.to_json(reply), loop_end, run.model.card.name, run.iteration, stopped_by
