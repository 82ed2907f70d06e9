"""uvicorn's httptools protocol with the connection limits it lacks.

* **Every connection counts** (``service/guards/connections.py``): HTTP connections and the WebSockets
  they upgrade to share ``max_connections``. A newcomer to a full table evicts the connection
  that has waited longest without a request under way (an unfinished head, an idle keep-alive,
  a WebSocket that has not sent its request), so slow senders and idle sockets cannot keep out a
  client that sends its request. When every connection is busy, the newcomer may still ask
  ``GET /healthz`` or ``GET /readyz`` in the probe lane; anything else there gets the JSON 503.
  uvicorn's own ``limit_concurrency`` (a plain 503 once the count is reached, whoever holds the
  slots, and blind to upgrades) is not used.
* **A deadline for the head**: the request line and headers must arrive within
  ``header_timeout_s`` of the connection's (or the kept-alive request's) first byte, and fit in
  ``max_header_bytes`` (else 431). The deadline is fixed when the head begins: a byte every
  half-second does not renew it.
* **The estimate gate's 503 before the app** (``service/guards/front_gate.py``): where every
  estimate slot is taken, a pose, alignment or scene request is answered as soon as its head is in,
  without the app's Python: 0.15-0.18 ms of the server's CPU a refusal instead of 0.26-0.35.
* **The request's first byte**: its ``time.perf_counter()`` goes into the scope (``ARRIVED``),
  so a request's budget and ``elapsed_ms`` count from when its first byte was read, not from when
  the app got round to it.
"""

from __future__ import annotations

import asyncio
import time
import weakref
from functools import partial
from typing import Any

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
from uvicorn.server import ServerState

from itnet.service.errors import ServiceError
from itnet.service.guards.byte_budget import ByteBudget
from itnet.service.guards.connections import Admission, ConnectionTable, Phase
from itnet.service.guards.front_gate import front_gate
from itnet.service.metrics import ARRIVED
from itnet.service.settings import ServerSettings

PROBES = frozenset({b"/healthz", b"/readyz"})
_tables: weakref.WeakKeyDictionary[ServerState, ConnectionTable] = weakref.WeakKeyDictionary()
_ws_budgets: weakref.WeakKeyDictionary[ServerState, ByteBudget] = weakref.WeakKeyDictionary()


class Limits:
    """The connection limits of the servers started from now on in this process."""

    server = ServerSettings()
    retry_after_s = 1

    @classmethod
    def table(cls, state: ServerState) -> ConnectionTable:
        """The connection table of one uvicorn server (HTTP and WebSocket protocols share it)."""
        if state not in _tables:
            _tables[state] = ConnectionTable(
                cls.server.max_connections, cls.server.probe_connections
            )
        return _tables[state]

    @classmethod
    def ws_budget(cls, state: ServerState) -> ByteBudget:
        """The bytes of WebSocket messages being received, all connections of one server."""
        if state not in _ws_budgets:
            _ws_budgets[state] = ByteBudget(cls.server.ws_buffer_bytes)
        return _ws_budgets[state]


def overloaded_body(retry_after_s: int, detail: str) -> tuple[bytes, list[tuple[bytes, bytes]]]:
    """The JSON 503 (``kind: overloaded``) with ``Retry-After`` and ``connection: close``."""
    headers = {"Retry-After": str(retry_after_s), "connection": "close"}
    return ServiceError(503, "overloaded", detail, headers).encoded()


def raw_reply(transport: asyncio.BaseTransport, status: bytes, body: bytes,
              headers: list[tuple[bytes, bytes]]) -> None:  # fmt: skip
    """Write a whole HTTP/1.1 response straight to the socket and close it."""
    if transport.is_closing():
        return
    head = b"".join(name + b": " + value + b"\r\n" for name, value in headers)
    transport.write(b"HTTP/1.1 " + status + b"\r\n" + head + b"\r\n" + body)  # type: ignore[attr-defined]
    transport.close()


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """HttpToolsProtocol with the connection table, the head's deadline and size, arrival."""

    @classmethod
    def configure(cls, server: ServerSettings, retry_after_s: int = 1) -> None:
        """Set the limits of every server started from now on (in this process)."""
        Limits.server, Limits.retry_after_s = server, retry_after_s

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.table = Limits.table(self.server_state)
        self._head_timer: asyncio.TimerHandle | None = None
        self._head_bytes = 0
        self._tail = b""  # the last bytes seen, in case the blank line spans two reads
        self._data_at = time.perf_counter()

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        if self.table.open(transport, self._evict) is Admission.REFUSED:
            self._refuse("too many connections")
            return
        self._start_head()

    def connection_lost(self, exc: Exception | None) -> None:
        self._stop_head()
        self.table.close(self.transport)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        self._data_at = time.perf_counter()
        if self._head_timer is not None:  # count the head's bytes, not the body's behind it
            window = self._tail + data
            end = window.find(b"\r\n\r\n")
            self._head_bytes += len(data) if end < 0 else max(0, end + 4 - len(self._tail))
            self._tail = window[-3:]
            if self._head_bytes > Limits.server.max_header_bytes:
                self._refuse_head()
                return
        super().data_received(data)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self.scope[ARRIVED] = self._data_at  # type: ignore[literal-required]
        if self._head_timer is None:  # a keep-alive connection's next request
            self.table.set_phase(self.transport, Phase.HEAD)
            self._start_head()

    def on_headers_complete(self) -> None:
        self._stop_head()
        self.table.set_phase(self.transport, Phase.BUSY)
        if self.parser.should_upgrade() and self._should_upgrade():
            super().on_headers_complete()  # an upgrade in the lane is refused at the handover
            return
        if self.table.in_lane(self.transport) and not self._is_probe():
            self._answer_with(self._overloaded)  # the probe lane serves probes only
            return
        gate = front_gate(self.server_state, self.app)
        method, path = self.parser.get_method(), httptools.parse_url(self.url).path
        refused = None if gate is None else gate.refusal(method.decode(), path.decode())
        if gate is None or refused is None:
            super().on_headers_complete()
            return
        self._answer_with(partial(gate.reply, refused))

    def handle_websocket_upgrade(self) -> None:
        if self.table.in_lane(self.transport):
            self._refuse("too many connections")
            return
        super().handle_websocket_upgrade()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            busy = self.cycle is not None and not self.cycle.response_complete  # pipelined
            self.table.set_phase(self.transport, Phase.BUSY if busy else Phase.IDLE)

    def _answer_with(self, app: Any) -> None:
        """Run this request's cycle with ``app`` instead of the service's (its body unread)."""
        service = self.app
        self.app = app
        try:
            super().on_headers_complete()
        finally:
            self.app = service

    def _is_probe(self) -> bool:
        method = self.parser.get_method()
        return method in (b"GET", b"HEAD") and httptools.parse_url(self.url).path in PROBES

    async def _overloaded(self, scope: Any, receive: Any, send: Any) -> None:
        """The ASGI reply in the probe lane: JSON 503 with Retry-After, then close."""
        body, headers = overloaded_body(
            Limits.retry_after_s,
            f"too many connections; retry in {Limits.retry_after_s} s",
        )
        await send({"type": "http.response.start", "status": 503, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    def _refuse(self, why: str) -> None:
        body, headers = overloaded_body(
            Limits.retry_after_s, f"{why}; retry in {Limits.retry_after_s} s"
        )
        self._stop_head()
        raw_reply(self.transport, b"503 Service Unavailable", body, headers)

    def _evict(self) -> None:
        """Chosen to make room (service/guards/connections.py): close without a word."""
        self._stop_head()
        if not self.transport.is_closing():
            self.transport.close()

    def _start_head(self) -> None:
        self._head_bytes, self._tail = 0, b""
        self._head_timer = self.loop.call_later(
            Limits.server.header_timeout_s, self._head_timed_out
        )

    def _stop_head(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_timed_out(self) -> None:
        self._head_timer = None
        if not self.transport.is_closing():
            self.transport.close()

    def _refuse_head(self) -> None:
        self._stop_head()
        limit = Limits.server.max_header_bytes
        body, headers = ServiceError(
            431, "too_large", f"request line and headers exceed {limit} bytes",
            {"connection": "close"},
        ).encoded()  # fmt: skip
        raw_reply(self.transport, b"431 Request Header Fields Too Large", body, headers)
