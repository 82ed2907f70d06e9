"""A budget of request bytes held in memory, shared by every request of a server.

A request body (or a WebSocket message) takes its bytes from the budget *before* they are
buffered: all at once from a declared ``Content-Length``, or chunk by chunk as a body without
one arrives. A request that does not fit is refused at once (503 ``overloaded`` with
``Retry-After``) instead of being buffered, so the memory that uploads can pin is bounded by the
budget, whatever their number or speed. Bytes go back when the request is done with them.

Large requests (``large`` bytes or more) may fill only ``1 - small_share`` of the budget: the
rest stays for ordinary requests, so uploads that announce the body limit and stall cannot
refuse everyone else.
Once every byte is back after at least ``trim_bytes`` were taken, the freed heap is handed back
to the OS (``service/heap.py``): glibc would otherwise keep what stalled uploads or frames held.
Thread-safe (a worker thread may hand bytes back).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

from itnet.service.errors import ServiceError
from itnet.service.heap import return_freed_memory_soon


class ByteBudget:
    """``total`` bytes; ``take(n)`` -> whether they were granted; ``give(n)`` returns them."""

    def __init__(
        self, total: int, large: int = 2**20, small_share: float = 0.25, trim_bytes: int = 8 * 2**20
    ) -> None:
        if total < 1:
            raise ValueError(f"a byte budget needs at least one byte, got {total}")
        self.total, self.large = total, large
        self.small_reserve = int(total * small_share)
        self._held = 0
        self.trim_bytes, self._taken_since_trim, self.trims = trim_bytes, 0, 0
        self._lock = threading.Lock()
        self.refused = 0

    @property
    def held(self) -> int:
        return self._held

    def take(self, n: int, whole: int | None = None) -> bool:
        """Take ``n`` more bytes for a request that holds ``whole`` bytes with them (default
        ``n``; it decides whether the request is large)."""
        with self._lock:
            free = self.total - self._held
            large = (n if whole is None else whole) >= self.large
            if n > free or (large and n > free - self.small_reserve):
                self.refused += 1
                return False
            self._held += n
            self._taken_since_trim += n
            return True

    def give(self, n: int) -> None:
        with self._lock:
            self._held = max(0, self._held - n)
            trim = self._held == 0 and self._taken_since_trim >= self.trim_bytes
            if trim:
                self._taken_since_trim, self.trims = 0, self.trims + 1
        if trim:
            return_freed_memory_soon()

    @contextmanager
    def hold(self, n: int, retry_after_s: int) -> Iterator[None]:
        """Hold ``n`` bytes for the block, or raise the 503 that says the server is full."""
        if not self.take(n):
            raise self.full(n, retry_after_s)
        try:
            yield
        finally:
            self.give(n)

    def full(self, n: int, retry_after_s: int) -> ServiceError:
        mib = 2**20
        return ServiceError(
            503,
            "overloaded",
            f"the server holds {self.held / mib:.0f} MiB of requests (the limit is "
            f"{self.total / mib:.0f} MiB) and this one needs {n / mib:.1f} MiB more; retry in "
            f"{retry_after_s} s",
            headers={"Retry-After": str(retry_after_s), "Connection": "close"},
        )
