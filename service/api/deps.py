"""Dependencies of the routes, as ``Annotated`` aliases."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request
from starlette.requests import HTTPConnection

from itnet.service.errors import ServiceError, too_large
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
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise too_large(size, limit, what="request body (at least)")
        chunks.append(chunk)
    return b"".join(chunks)


BodyDep = Annotated[bytes, Depends(read_body)]
