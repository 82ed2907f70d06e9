"""Graceful shutdown for WebSocket streams: on SIGTERM, every stream in flight stops at its next
step and gets its final ``result`` (the best estimate so far) before the connections close.

uvicorn drains HTTP requests on SIGTERM but closes WebSocket connections at once (code 1012),
so a client streaming an estimate would lose it. ``StreamDrain.install`` (called at start-up,
when uvicorn's own signal handler is in place) chains a handler in front of uvicorn's: it
cancels every tracked stream run, waits until the streams have answered (at most ``grace_s``),
then hands the signal to uvicorn, which stops accepting connections and drains the rest.
Streams that arrive in between are refused (503, close 1013). One instance per process: each
worker process installs its own.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

log = logging.getLogger("itnet.service")

# A stream needs only to finish the step under way and send one message: half a second is
# plenty, and keeps the port open for new connections only that long after the signal.
DEFAULT_GRACE_S = 0.5


class StreamDrain:
    """The stream runs in flight (anything with ``cancel()``), and whether shutdown has begun."""

    def __init__(self, grace_s: float = DEFAULT_GRACE_S) -> None:
        self.grace_s = grace_s
        self.draining = threading.Event()
        self._runs: set[Any] = set()
        self._lock = threading.Lock()

    @contextmanager
    def track(self, run: Any) -> Iterator[None]:
        """Keep ``run`` on the list while the stream serves it (cancelled at once if shutdown
        has already begun)."""
        with self._lock:
            self._runs.add(run)
            if self.draining.is_set():
                run.cancel()
        try:
            yield
        finally:
            with self._lock:
                self._runs.discard(run)

    def in_flight(self) -> int:
        with self._lock:
            return len(self._runs)

    def begin(self) -> None:
        """Shutdown has begun: cancel every run in flight, and every one tracked from now on."""
        self.draining.set()
        with self._lock:
            runs = list(self._runs)
        for run in runs:
            run.cancel()
        log.info("shutting down: %d stream(s) stopping with their final result", len(runs))

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until no run is tracked (True) or ``timeout_s`` has passed (False)."""
        deadline = time.monotonic() + timeout_s
        while self.in_flight() and time.monotonic() < deadline:
            time.sleep(0.005)
        return not self.in_flight()

    def install(self) -> bool:
        """Put ``begin`` in front of the process's SIGTERM handler (uvicorn's, at start-up).
        Only the main thread can; elsewhere (a server in a test thread) nothing happens.
        Returns whether it was installed."""
        if threading.current_thread() is not threading.main_thread():
            return False
        previous = signal.getsignal(signal.SIGTERM)
        if not callable(previous):
            return False

        def handler(signum: int, frame: FrameType | None) -> None:
            self.begin()
            # Hand over once the streams have answered; the handler itself must return at once.
            threading.Thread(
                target=self._hand_over, args=(previous, signum, frame), daemon=True
            ).start()

        signal.signal(signal.SIGTERM, handler)
        return True

    def _hand_over(
        self, previous: Callable[[int, FrameType | None], Any], signum: int, frame: FrameType | None
    ) -> None:
        if not self.wait_idle(self.grace_s):
            log.warning("%d stream(s) still running after %.1f s", self.in_flight(), self.grace_s)
        previous(signum, frame)
