"""Dependencies of the routes, as ``Annotated`` aliases."""

from __future__ import annotations

import time
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, Request
from starlette.requests import HTTPConnection

from itnet.service.guards.body import limited_body
from itnet.service.metrics import ARRIVED
from itnet.service.state import ServiceState

# The plain lookups below are ``async def`` on purpose: FastAPI runs a ``def`` dependency in a
# worker thread, and those two thread hops cost a request about 0.5 ms of its budget on 2 cores.


async def get_state(connection: HTTPConnection) -> ServiceState:
    """The app's state (HTTP requests and WebSockets alike)."""
    return connection.app.state.service


StateDep = Annotated[ServiceState, Depends(get_state)]


async def gate_open(state: StateDep) -> None:
    """The gate's 503 at once, before the body is read, when every estimate slot is taken (a
    refused request's body is neither read nor taken from the byte budget). The slot itself is
    taken once the body is in, so a slow uploader cannot hold one."""
    state.gate.check()


async def arrival(connection: HTTPConnection) -> float:
    """``time.perf_counter()`` when the request reached the app (now, if nobody recorded it)."""
    arrived = connection.scope.get(ARRIVED)
    return float(arrived) if arrived is not None else time.perf_counter()


ArrivedDep = Annotated[float, Depends(arrival)]


async def read_body(request: Request, state: StateDep, arrived: ArrivedDep) -> AsyncIterator[bytes]:
    """The request body under the server's limits (``service/guards/body.py``: size, encoding, the
    byte budget, a deadline from the first byte), held in the budget until the request ends."""
    limits = state.settings.limits
    async with limited_body(request, limits, state.buffers, arrived) as body:
        yield body


GateOpenDep = Annotated[None, Depends(gate_open)]
BodyDep = Annotated[bytes, Depends(read_body)]
