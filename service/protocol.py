"""uvicorn's httptools protocol with two limits it lacks (a header timeout and a header size cap)
and the service's own refusal beyond ``limit_concurrency``.

uvicorn times out idle keep-alive connections, but not a connection that never finishes its
request line and headers (slowloris), and httptools accepts headers of any size. Such connections
also count toward ``limit_concurrency``, so a handful of silent sockets could turn every real
request into a 503. Here a request's line and headers must arrive within ``header_timeout_s`` and
fit in ``max_header_bytes``; otherwise the connection is closed (with a 431 for oversize headers).

Beyond ``limit_concurrency`` (``max_connections``) uvicorn answers a plain-text 503 with no
``Retry-After``; here it is the same JSON 503 (``kind: overloaded``) with ``Retry-After`` that the
estimate gate sends, so a client handles both the same way.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from itnet.service.settings import ServerSettings


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """HttpToolsProtocol that bounds the time and bytes of each request's head."""

    header_timeout_s: float = ServerSettings().header_timeout_s
    max_header_bytes: int = ServerSettings().max_header_bytes
    retry_after_s: int = 1

    @classmethod
    def configure(cls, server: ServerSettings, retry_after_s: int = 1) -> None:
        """Set the limits of every connection served from now on (in this process), and the
        ``Retry-After`` of the 503 beyond ``max_connections``."""
        cls.header_timeout_s = server.header_timeout_s
        cls.max_header_bytes = server.max_header_bytes
        cls.retry_after_s = retry_after_s

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._head_timer: asyncio.TimerHandle | None = None
        self._head_bytes = 0
        self._tail = b""  # the last bytes seen, in case the blank line spans two reads

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._start_head()

    def on_message_begin(self) -> None:
        super().on_message_begin()
        if self._head_timer is None:  # a keep-alive connection's next request
            self._start_head()

    def data_received(self, data: bytes) -> None:
        if self._head_timer is not None:  # count the head's bytes, not the body's behind it
            window = self._tail + data
            end = window.find(b"\r\n\r\n")
            self._head_bytes += len(data) if end < 0 else max(0, end + 4 - len(self._tail))
            self._tail = window[-3:]
            if self._head_bytes > self.max_header_bytes:
                self._refuse_head()
                return
        super().data_received(data)

    def on_headers_complete(self) -> None:
        self._stop_head()
        if not self._over_limit() or self.parser.should_upgrade():
            super().on_headers_complete()
            return
        # uvicorn would answer with its plain-text 503: let it run the cycle with ours instead.
        app, limit = self.app, self.limit_concurrency
        self.app, self.limit_concurrency = self._overloaded, None
        try:
            super().on_headers_complete()
        finally:
            self.app, self.limit_concurrency = app, limit
        self.logger.warning("Exceeded concurrency limit.")

    def _over_limit(self) -> bool:
        limit = self.limit_concurrency
        return limit is not None and (len(self.connections) >= limit or len(self.tasks) >= limit)

    async def _overloaded(self, scope: Any, receive: Any, send: Any) -> None:
        """The ASGI reply beyond ``limit_concurrency``: JSON 503 with Retry-After, then close."""
        body = json.dumps(
            {"detail": f"too many connections; retry in {self.retry_after_s} s",
             "kind": "overloaded"}
        ).encode()  # fmt: skip
        headers = [(b"content-type", b"application/json"),
                   (b"content-length", str(len(body)).encode()),
                   (b"retry-after", str(self.retry_after_s).encode()), (b"connection", b"close")]  # fmt: skip
        await send({"type": "http.response.start", "status": 503, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    def connection_lost(self, exc: Exception | None) -> None:
        self._stop_head()
        super().connection_lost(exc)

    def _start_head(self) -> None:
        self._head_bytes, self._tail = 0, b""
        self._head_timer = self.loop.call_later(self.header_timeout_s, self._head_timed_out)

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
        body = json.dumps(
            {
                "detail": f"request line and headers exceed {self.max_header_bytes} bytes",
                "kind": "too_large",
            }
        ).encode()
        head = (
            "HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-type: application/json\r\n"
            f"content-length: {len(body)}\r\nconnection: close\r\n\r\n"
        )
        if not self.transport.is_closing():
            self.transport.write(head.encode() + body)
            self.transport.close()
