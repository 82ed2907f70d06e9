"""Dependencies of the routes, as ``Annotated`` aliases."""

from __future__ import annotations

import time
from typing import Annotated

import anyio
from fastapi import Depends, Request
from starlette.requests import ClientDisconnect, HTTPConnection

from itnet.service.errors import ServiceError, too_large
from itnet.service.metrics import ARRIVED
from itnet.service.state import ServiceState


def get_state(connection: HTTPConnection) -> ServiceState:
    """The app's state (HTTP requests and WebSockets alike)."""
    return connection.app.state.service


StateDep = Annotated[ServiceState, Depends(get_state)]


async def read_body(request: Request, state: StateDep) -> bytes:
    """The request body, refused with a 413 as soon as it is known to exceed the limit: from the
    Content-Length header before reading, or while streaming a chunked body."""
    limit = state.settings.limits.max_body_bytes
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.isdigit():
            raise ServiceError(400, "invalid_request", f"invalid Content-Length {declared!r}")
        if int(declared) > limit:
            raise too_large(int(declared), limit)
    chunks, size = [], 0
    timeout = state.settings.limits.body_timeout_s
    try:
        with anyio.fail_after(timeout):  # a client that trickles its body must not hold a slot
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise too_large(size, limit, what="request body (at least)")
                chunks.append(chunk)
    except TimeoutError:
        raise ServiceError(
            408, "timeout", f"the request body did not arrive within {timeout:g} s"
        ) from None
    except ClientDisconnect:  # nobody is left to answer; 499 is nginx's code, kept for metrics
        raise ServiceError(
            499, "disconnected", "the client disconnected before its body arrived"
        ) from None
    return b"".join(chunks)


def arrival(connection: HTTPConnection) -> float:
    """``time.perf_counter()`` when the request reached the app (now, if nobody recorded it)."""
    arrived = connection.scope.get(ARRIVED)
    return float(arrived) if arrived is not None else time.perf_counter()


BodyDep = Annotated[bytes, Depends(read_body)]
ArrivedDep = Annotated[float, Depends(arrival)]
