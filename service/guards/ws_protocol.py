"""uvicorn's WebSocket protocol (websockets, sans-I/O) with the limits it lacks.

* The connection stays in the server's connection table (``service/guards/connections.py``) after the
  upgrade: ``WS_WAIT`` (evictable) until its first message, ``BUSY`` after.
* The bytes of messages being received, over every connection, come from one budget
  (``ws_buffer_bytes``). The websockets library refuses a frame whose header announces more than
  ``ws_max_size`` before reading its payload, but it buffers any smaller one until its last byte
  arrives: thirty clients that each send all but the last byte of a 16 MiB frame held 480 MiB.
  Here a connection whose partial message would overflow the budget is closed (1013, try again
  later) instead. Messages in many fragments are capped at ``MAX_FRAGMENTS`` (empty fragments
  cost nothing on the wire but a list entry each here).
* A text message that is not UTF-8 closes the connection with 1007 and one log line (uvicorn
  logs a traceback per message).
* Each message carries ``ARRIVED``: when the first byte of its first frame was read, so a
  stream's budget counts from its request's arrival.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from websockets.frames import Frame

from itnet.service.guards.connections import Phase
from itnet.service.guards.protocol import Limits
from itnet.service.metrics import ARRIVED

MAX_FRAGMENTS = 1024
TRY_LATER, BAD_DATA, TOO_BIG = 1013, 1007, 1009


class GuardedWebSocketProtocol(WebSocketsSansIOProtocol):
    """WebSocketsSansIOProtocol under the connection table and the message byte budget."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.table = Limits.table(kwargs.get("server_state") or args[1])
        self.budget = Limits.ws_budget(kwargs.get("server_state") or args[1])
        self._held = 0  # bytes of this connection's unfinished message, taken from the budget
        self._fragment_bytes = 0
        self._message_at = time.perf_counter()
        self._requested = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        self.table.adopt(transport, self._evict, Phase.WS_WAIT)

    def connection_lost(self, exc: Exception | None) -> None:
        self.table.close(self.transport)
        # Free the unfinished message now: the protocol object may live on in a reference
        # cycle until a full garbage collection (rare, with the start-up objects frozen), and
        # with it up to ws_max_size of buffer (the stalled-frame attack left 62 MiB behind).
        self.conn.reader.buffer.clear()
        self.frames, self._fragment_bytes = [], 0
        self._hold(0)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._held == 0:  # these bytes begin a frame
            self._message_at = time.perf_counter()
        super().data_received(data)
        if self.transport.is_closing():
            self._hold(0)
            return
        held = len(self.conn.reader.buffer) + self._fragment_bytes
        if not self._hold(held):
            self._fail(TRY_LATER, "the server holds too many unfinished messages; retry later")

    def handle_text(self, event: Frame) -> None:
        self._fragment_bytes = len(event.data)
        super().handle_text(event)

    def handle_bytes(self, event: Frame) -> None:
        self._fragment_bytes = len(event.data)
        super().handle_bytes(event)

    def handle_cont(self, event: Frame) -> None:
        if len(self.frames) >= MAX_FRAGMENTS:
            self._fail(TOO_BIG, f"a message may have at most {MAX_FRAGMENTS} fragments")
            return
        self._fragment_bytes += len(event.data)
        super().handle_cont(event)

    def send_receive_event_to_app(self) -> None:
        """uvicorn's, with the arrival time, and invalid UTF-8 closed without a traceback."""
        data = self.frames[0] if len(self.frames) == 1 else b"".join(self.frames)
        self.frames, self._fragment_bytes = [], 0
        if self.close_sent:
            return
        event: dict[str, Any] = {"type": "websocket.receive", ARRIVED: self._message_at}
        if self.curr_msg_data_type == "text":
            try:
                event["text"] = bytes(data).decode()
            except UnicodeDecodeError:
                self.logger.info("WebSocket text message is not UTF-8: closed with 1007")
                self._fail(BAD_DATA, "text messages must be UTF-8")
                return
        else:
            event["bytes"] = bytes(data)
        if not self._requested:
            self._requested = True
            self.table.set_phase(self.transport, Phase.BUSY)
        self.queue.put_nowait(event)  # type: ignore[arg-type]
        if not self.read_paused:
            self.read_paused = True
            self.transport.pause_reading()

    def handle_parser_exception(self) -> None:
        """uvicorn's asserts that a close frame was queued; a protocol error before the handshake
        is answered (frames sent before the 101, which RFC 6455 forbids) has none, and logged an
        AssertionError traceback per connection: closed here with one log line."""
        if self.conn.close_sent is not None:
            super().handle_parser_exception()
            return
        self.logger.info("WebSocket protocol error (%s): connection closed", self.conn.parser_exc)
        self.queue.put_nowait({"type": "websocket.disconnect", "code": 1002, "reason": "protocol"})
        self._hold(0)
        self.transport.close()

    def _hold(self, held: int) -> bool:
        """Hold ``held`` bytes for this connection (0: hand them all back); False if the budget
        cannot give more."""
        if held > self._held and not self.budget.take(held - self._held):
            return False
        if held < self._held:
            self.budget.give(self._held - held)
        self._held = held
        return True

    def _evict(self) -> None:
        """Chosen to make room (service/guards/connections.py): close 1013 (try again later)."""
        self._fail(TRY_LATER, "the server is full; retry later")

    def _fail(self, code: int, reason: str) -> None:
        if self.transport.is_closing():
            return
        if self.handshake_complete and not self.close_sent:
            self.conn.fail(code, reason)
            self.transport.write(b"".join(self.conn.data_to_send()))
            self.close_sent = True
        self.queue.put_nowait({"type": "websocket.disconnect", "code": code, "reason": reason})
        self._hold(0)
        self.transport.close()
