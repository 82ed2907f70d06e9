"""Step slots handed out earliest deadline first.

A model runs at most ``slots`` steps at once (more would share the cores and each would take
longer than the engine predicted). When every slot is busy, waiting runs queue, and a freed slot
goes to the waiter whose budget ends first, not to whichever thread grabs it first. With a plain
semaphore a run that just finished a step takes the slot again before a woken waiter can, so
a new request could wait out its whole budget behind older runs that keep stepping.
"""

from __future__ import annotations

import heapq
import itertools
import threading
from dataclasses import dataclass, field


@dataclass(order=True)
class _Waiter:
    deadline: float
    seq: int
    granted: bool = field(default=False, compare=False)
    gone: bool = field(default=False, compare=False)
    event: threading.Event = field(default_factory=threading.Event, compare=False)


class StepSlots:
    """``slots`` slots; ``acquire(deadline, timeout_s)`` -> bool; ``release()`` after a grant."""

    def __init__(self, slots: int) -> None:
        if slots < 1:
            raise ValueError(f"need at least one slot, got {slots}")
        self._lock = threading.Lock()
        self._free = slots
        self._waiting: list[_Waiter] = []
        self._seq = itertools.count()

    def acquire(self, deadline: float, timeout_s: float) -> bool:
        """Take a slot: at once if one is free and nobody waits, else wait up to ``timeout_s``
        (no wait if <= 0) in deadline order. ``deadline`` is a ``time.perf_counter()`` value."""
        with self._lock:
            if self._free > 0 and not self._waiting:
                self._free -= 1
                return True
            if timeout_s <= 0:
                return False
            waiter = _Waiter(deadline, next(self._seq))
            heapq.heappush(self._waiting, waiter)
        waiter.event.wait(timeout_s)
        with self._lock:
            if waiter.granted:  # also when the grant raced the timeout: the slot is ours
                return True
            waiter.gone = True  # release() skips it
            return False

    def release(self) -> None:
        with self._lock:
            while self._waiting:
                waiter = heapq.heappop(self._waiting)
                if not waiter.gone:
                    waiter.granted = True
                    waiter.event.set()
                    return
            self._free += 1

    @property
    def waiting(self) -> int:
        with self._lock:
            return sum(not w.gone for w in self._waiting)
