"""How long a finished run's reply takes to leave the handler: what the engine must reserve.

The budget covers the reply, not only the steps. After the loop stops, the reply still has to be
serialised and handed back from the worker thread to the event loop, which under load waits for
the GIL and for the other requests' I/O. ``HandbackTimer`` keeps the recent hand-back times and
offers their 90th percentile as the time each new run keeps in reserve.
"""

from __future__ import annotations

import threading
import time
from collections import deque


class HandbackTimer:
    """Recent hand-back times (ms) of the last ``window_s`` seconds; ``reserve_ms()`` is their
    ``quantile``, capped at ``cap_ms`` (a stall must not starve every later run of steps)."""

    def __init__(self, window_s: float = 2.0, quantile: float = 0.99, cap_ms: float = 25.0) -> None:
        self.window_s, self.quantile, self.cap_ms = window_s, quantile, cap_ms
        self._lock = threading.Lock()
        self._times: deque[tuple[float, float]] = deque(maxlen=256)

    def record(self, ms: float, at: float | None = None) -> None:
        with self._lock:
            self._times.append((time.perf_counter() if at is None else at, max(0.0, ms)))

    def reserve_ms(self, now: float | None = None) -> float:
        now = time.perf_counter() if now is None else now
        with self._lock:
            recent = sorted(ms for at, ms in self._times if at >= now - self.window_s)
        if not recent:
            return 0.0
        return min(self.cap_ms, recent[min(len(recent) - 1, int(self.quantile * len(recent)))])
