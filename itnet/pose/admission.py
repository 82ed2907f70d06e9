"""Admission by work: a request runs only where the work already admitted leaves it room.

A run needs the steps of its plan up to the model's recommended iterations (``AnytimeRun.
needed_work_ms``: a default request needs its whole plan; one that asks for hundreds of
iterations within a long budget needs the usual ones, and takes the rest as the budget allows).
A new run is admitted when the work still ahead of the admitted runs, shared over the step slots
that serve them, plus its own, fits the budget it has left; else it is refused at once with a
503 and ``Retry-After`` (``OverloadedError``), before it takes a step. Refusing early keeps the
admitted runs on their plans: without it, many clients at once share the cores until none gets
its first step inside its budget.

A run alone is always admitted: its plan was fitted to its budget on an idle machine, and the
loop stops before it overruns (with no step at all it is refused the same way). A ``Catalog``
holds one: the service's requests, its alignments and every ``Catalog.pose`` of one process are
admitted together.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

from itnet.pose.errors import OverloadedError
from itnet.pose.loop import AnytimeRun


class Admission:
    """The runs admitted in one process, and the work they still need."""

    def __init__(self, retry_after_s: int = 1) -> None:
        self.retry_after_s = retry_after_s
        self._runs: list[AnytimeRun] = []
        self._lock = threading.Lock()

    @property
    def running(self) -> int:
        return len(self._runs)

    def ahead_ms(self, slots: int) -> float:
        """The admitted runs' remaining needed work, shared over ``slots`` step slots."""
        return sum(run.needed_work_ms() for run in self._runs) / max(1, slots)

    @contextmanager
    def admit(self, *runs: AnytimeRun) -> Iterator[None]:
        """Hold ``runs`` (one request's, e.g. an alignment's two clouds) among the admitted while
        they run; OverloadedError where they cannot fit together."""
        with self._lock:
            first = runs[0]
            ahead = self.ahead_ms(first.model.concurrent_steps)
            cost = sum(run.needed_work_ms() for run in runs)
            if self._runs and ahead + cost > min(run.left_ms() for run in runs):
                raise OverloadedError(
                    f"the server is busy: {len(self._runs)} estimate(s) need about {ahead:.0f} "
                    f"ms of steps, and this one about {cost:.0f} ms of its "
                    f"{first.plan.budget_ms:g} ms budget; retry in {self.retry_after_s} s",
                    self.retry_after_s,
                )
            self._runs.extend(runs)
        try:
            yield
        finally:
            with self._lock:
                for run in runs:
                    self._runs.remove(run)
