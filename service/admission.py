"""Admission by work: a request runs only where the work already admitted leaves its plan room.

Every admitted run holds its plan's predicted work (``AnytimeRun.planned_work_ms``: its steps at
the model's current step time) until it ends. A new run is admitted when the work ahead of it,
shared over the step slots that serve it, plus its own, fits the budget it has left; else it is
refused at once with a 503 and ``Retry-After`` (``OverloadedError``), before it takes a step.
Refusing early keeps the runs that were admitted on their plans: without it, many clients at
once share the cores until none gets its first step inside its budget.

A run alone is always admitted: its plan was fitted to its budget on an idle machine, and what
the loop does with a budget that turns out short is its own business (it stops before
overrunning; with no step at all it is refused the same way).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

from itnet.pose.errors import OverloadedError
from itnet.pose.loop import AnytimeRun


class Admission:
    """The admitted work of one process, in milliseconds of steps."""

    def __init__(self, retry_after_s: int = 1) -> None:
        self.retry_after_s = retry_after_s
        self.pending_ms = 0.0
        self.running = 0
        self._lock = threading.Lock()

    @contextmanager
    def admit(self, run: AnytimeRun) -> Iterator[None]:
        """Hold ``run``'s work while it runs; OverloadedError where it cannot fit."""
        cost = run.planned_work_ms()
        with self._lock:
            ahead = self.pending_ms / max(1, run.model.concurrent_steps)
            if self.running and ahead + cost > run.left_ms():
                raise OverloadedError(
                    f"the server is busy: {self.running} estimate(s) hold about {ahead:.0f} ms "
                    f"of steps, and this one needs about {cost:.0f} ms of its "
                    f"{run.plan.budget_ms:g} ms budget; retry in {self.retry_after_s} s",
                    self.retry_after_s,
                )
            self.pending_ms += cost
            self.running += 1
        try:
            yield
        finally:
            with self._lock:
                self.pending_ms -= cost
                self.running -= 1
