"""``WS /v1/estimate/stream``: the anytime estimate, one message per iteration as it exists.

Protocol (one request per connection):

1. client -> ``{"points": [[x, y, z], ...], "budget_ms": 50, ...}`` (the POST body, as text);
2. server -> ``{"type": "estimate", "iteration": 1, ...}`` after every step;
3. client may send ``{"type": "cancel"}`` at any time: the loop stops before its next step;
4. server -> ``{"type": "result", ...}`` (``stopped_by`` is ``cancelled`` after a cancel), then
   closes with 1000. When the server shuts down (SIGTERM) the run stops at its next step the
   same way, with ``stopped_by`` ``cancelled``, and the close code is 1001 (going away).

An error is ``{"type": "error", "detail": ..., "kind": ...}`` then a close: 1008 (bad request),
1003 (binary message), 1009 (too big), 1013 (busy), 1011 (server fault). A client that leaves
stops the work: no step starts after the disconnect is seen; so does one that does not take a
message within ``ws_send_timeout_s`` (a stalled reader). The budget counts from the request's
arrival (the first message).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass

import anyio
from fastapi import APIRouter, WebSocket
from starlette.websockets import WebSocketDisconnect

from itnet.pose.loop import AnytimeRun
from itnet.service.api.deps import StateDep
from itnet.service.errors import ServiceError, too_large
from itnet.service.metrics import ARRIVED
from itnet.service.schemas import StreamRequest
from itnet.service.state import ServiceState

router = APIRouter(prefix="/v1", tags=["estimate"])
log = logging.getLogger("itnet.service")
ENDPOINT = "/v1/estimate/stream"
SEND_ERRORS = (WebSocketDisconnect, RuntimeError, OSError)


@dataclass
class _Peer:
    """What the listening task learnt about the client while the run went on."""

    disconnected: bool = False


@router.websocket("/estimate/stream")
async def stream(websocket: WebSocket, state: StateDep) -> None:
    start, code = time.perf_counter(), 1000
    await websocket.accept()
    try:
        code = await _serve(websocket, state)
    except ServiceError as err:
        code = await _refuse(websocket, state, err)
    except Exception:  # a server fault: say so and close, never leave the client hanging
        log.exception("stream failed")
        code = await _refuse(websocket, state, ServiceError(500, "internal", "internal error"))
    finally:
        state.metrics.observe_request(ENDPOINT, f"ws_{code}", time.perf_counter() - start)


async def _serve(websocket: WebSocket, state: ServiceState) -> int:
    """Read the request, run it, stream it. Returns the close code (1006: the client left)."""
    first = await _first_message(websocket, state)
    if first is None:
        return 1006
    (text, arrived), send_timeout_s = first, state.settings.limits.ws_send_timeout_s
    if state.drain.draining.is_set():
        raise ServiceError(503, "shutting_down", "the server is shutting down")
    with state.gate.slot():
        with state.buffers.hold(len(text), state.settings.limits.retry_after_s):
            run = await anyio.to_thread.run_sync(_prepare, state, text, arrived)
        with state.drain.track(run), state.serving(run):
            if run.recognition is not None:  # model "auto": the category comes first
                await websocket.send_json(run.category_message())
            peer = await _stream_run(websocket, run, send_timeout_s)
    stopped_by = "disconnected" if peer.disconnected else str(run.stopped_by)
    state.metrics.observe_run(run.model.card.name, run.iteration, stopped_by)
    if peer.disconnected:
        return 1006
    code = 1001 if state.drain.draining.is_set() else 1000
    try:
        with anyio.fail_after(send_timeout_s):
            await websocket.send_json({"type": "result", **run.result()})
            await websocket.close(code)
    except (*SEND_ERRORS, TimeoutError):
        return 1006
    return code


async def _first_message(websocket: WebSocket, state: ServiceState) -> tuple[str, float] | None:
    """The request text and when its first byte was read, or None if the client left first."""
    limits = state.settings.limits
    try:
        with anyio.fail_after(limits.ws_request_timeout_s):
            message = await websocket.receive()
    except TimeoutError:
        raise ServiceError(
            408, "timeout", f"no request within {limits.ws_request_timeout_s:g} s"
        ) from None
    if message["type"] == "websocket.disconnect":
        return None
    if message.get("text") is None:
        raise ServiceError(
            415, "unsupported_media_type", "send the request as a JSON text message, not binary"
        )
    text: str = message["text"]
    size = len(text) if text.isascii() else len(text.encode("utf-8"))
    if size > limits.max_ws_message_bytes:
        raise too_large(size, limits.max_ws_message_bytes, what="message")
    return text, float(message.get(ARRIVED, time.perf_counter()))


def _prepare(state: ServiceState, text: str, arrived: float) -> AnytimeRun:
    points, request = state.decoder.json(text, schema=StreamRequest)
    return state.start_run(points, request, arrived)


async def _stream_run(websocket: WebSocket, run: AnytimeRun, send_timeout_s: float) -> _Peer:
    """Step the run in a worker thread, one step at a time, sending each estimate; meanwhile
    listen for a cancel or a disconnect, either of which cancels the run before its next step.
    A send that the client does not take within ``send_timeout_s`` counts as a disconnect."""
    peer = _Peer()
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(_listen, websocket, run, peer)
        while not peer.disconnected:
            estimate = await anyio.to_thread.run_sync(next, run, None)
            if estimate is None or peer.disconnected:
                break
            try:
                with anyio.fail_after(send_timeout_s):
                    await websocket.send_json({"type": "estimate", **estimate.to_dict()})
            except (*SEND_ERRORS, TimeoutError):
                peer.disconnected = True
                run.cancel()
        tasks.cancel_scope.cancel()
    return peer


async def _listen(websocket: WebSocket, run: AnytimeRun, peer: _Peer) -> None:
    """Cancel the run on ``{"type": "cancel"}`` or on disconnect; other messages are ignored."""
    while True:
        try:
            message = await websocket.receive()
        except SEND_ERRORS:
            message = {"type": "websocket.disconnect"}
        if message["type"] == "websocket.disconnect":
            peer.disconnected = True
            run.cancel()
            return
        if _is_cancel(message.get("text")):
            run.cancel()


def _is_cancel(text: str | None) -> bool:
    if not text or len(text) > 1024:
        return False
    try:
        message = json.loads(text)
    except ValueError:
        return False
    return isinstance(message, dict) and message.get("type") == "cancel"


async def _refuse(websocket: WebSocket, state: ServiceState, err: ServiceError) -> int:
    """Send the error message and close with the fitting code."""
    state.metrics.observe_error(err.kind)
    try:
        with anyio.fail_after(state.settings.limits.ws_send_timeout_s):
            await websocket.send_json({"type": "error", **err.body()})
            await websocket.close(err.ws_close_code, reason=err.kind)
    except (*SEND_ERRORS, TimeoutError):
        return 1006
    return err.ws_close_code
