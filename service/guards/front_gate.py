"""The estimate gate's 503 given by the protocol, before the app runs.

Under overload most requests are refused. Refused by the app, each one costs the event loop
0.26-0.35 ms of the server's CPU (the middleware, the router, the dependencies, the error
handler), refused here 0.15-0.18 ms (``python -m benchmarks.refusal_cost``), and that time is
taken from the admitted runs: their threads wait for the interpreter lock between network steps
while the loop holds it. So the protocol asks the gate as soon as a
request's head is in (``GuardedHttpToolsProtocol.on_headers_complete``) and, where every slot is
taken, answers with the same reply the app would give (status 503, ``{"detail", "kind":
"overloaded"}``, ``Retry-After``), counted in the same metrics, without reading the body (the
connection stays open: uvicorn drops the unread body). Where the protocol is not ours (a test
client, another server), the route's own check (``service/api/deps.py``, ``gate_open``) gives it.
"""

from __future__ import annotations

import time
import weakref
from typing import Any

from itnet.service.errors import ServiceError
from itnet.service.metrics import ARRIVED, Metrics
from itnet.service.state import ConcurrencyGate, ServiceState

# The routes that ask the gate before their body (``Depends(gate_open)``); a test holds the two
# lists equal.
GATED_PATHS = frozenset({"/v1/estimate", "/v1/align", "/v1/scene"})
_DEPTH = 16  # wrappers around the app looked through (uvicorn's proxy headers, a logger)


class FrontGate:
    """One app's gate and metrics, as the protocol sees them."""

    def __init__(self, gate: ConcurrencyGate, metrics: Metrics) -> None:
        self.gate, self.metrics = gate, metrics

    @classmethod
    def of(cls, app: Any) -> FrontGate | None:
        """The gate of the service app ``app`` wraps (None where it is another app)."""
        for _ in range(_DEPTH):
            service = getattr(getattr(app, "state", None), "service", None)
            if isinstance(service, ServiceState):
                return cls(service.gate, service.metrics)
            app = getattr(app, "app", None)
            if app is None:
                return None
        return None

    def refusal(self, method: str, path: str) -> ServiceError | None:
        """The 503 for a ``method`` ``path`` request now, or None where it goes to the app."""
        if method != "POST" or path not in GATED_PATHS:
            return None
        return self.gate.refusal()

    async def reply(self, refused: ServiceError, scope: Any, receive: Any, send: Any) -> None:
        """An ASGI app that answers ``refused`` and counts it as the app's handlers would."""
        body, headers = refused.encoded()
        await send({"type": "http.response.start", "status": refused.status, "headers": headers})
        await send({"type": "http.response.body", "body": body})
        self.metrics.observe_error(refused.kind)
        arrived = scope.get(ARRIVED, time.perf_counter())
        self.metrics.observe_request(scope["path"], refused.status, time.perf_counter() - arrived)


_front_gates: weakref.WeakKeyDictionary[Any, FrontGate | None] = weakref.WeakKeyDictionary()


def front_gate(server_state: Any, app: Any) -> FrontGate | None:
    """The front gate of one uvicorn server (found once, then kept with its state)."""
    if server_state not in _front_gates:
        _front_gates[server_state] = FrontGate.of(app)
    return _front_gates[server_state]
