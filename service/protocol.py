"""uvicorn's httptools protocol with two limits it lacks: a header timeout and a header size cap.

uvicorn times out idle keep-alive connections, but not a connection that never finishes its
request line and headers (slowloris), and httptools accepts headers of any size. Such connections
also count toward ``limit_concurrency``, so a handful of silent sockets could turn every real
request into a 503. Here a request's line and headers must arrive within ``header_timeout_s`` and
fit in ``max_header_bytes``; otherwise the connection is closed (with a 431 for oversize headers).
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

    @classmethod
    def configure(cls, server: ServerSettings) -> None:
        """Set the limits of every connection served from now on (in this process)."""
        cls.header_timeout_s = server.header_timeout_s
        cls.max_header_bytes = server.max_header_bytes

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
        super().on_headers_complete()

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
