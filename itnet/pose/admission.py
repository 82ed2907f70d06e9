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
admitted together; the worker processes of ``itnet serve --workers N`` share what they admitted
through a file (``itnet.pose.shared_work``), so that together they admit one machine's worth.

The work counted is the model's step time, which cannot see what else takes the cores (the
clients on the same machine, the server's own parsing and replies). So the admission also
learns from what it delivers (``DeliveryLimit``): each finished run says whether it got at
least ``DELIVERED_SHARE`` of the iterations its budget gives on an idle machine; a run that
did not lowers the number of runs admitted at once, runs that did raise it again (additive
increase, multiplicative decrease, as TCP finds a link's rate). The service's gate refuses
beyond it before reading a request's body.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from itnet.pose.errors import OverloadedError
from itnet.pose.loop import AnytimeRun
from itnet.pose.shared_work import SharedWork

# a run served with less of its idle-machine iterations was starved. At 0.8, sixteen threaded
# clients at 20 ms got a median 7 of 10 iterations (four runs of python -m benchmarks.load_test
# --clients-kind threads, docs/service.md); at 0.95, 8 of 10, as many good answers a second
DELIVERED_SHARE = 0.95
DECREASE = 0.7  # the limit's cut after a starved run
DEFAULT_CEILING = 64.0  # runs at once where no ceiling is given (the service gives its gate's)


class DeliveryLimit:
    """How many runs at once the machine now serves with their iterations: additive increase
    (1 / limit a run served in full), multiplicative decrease (``DECREASE`` a starved run, at
    most once per ``window`` of the starved run's budget, so one overloaded moment's runs cut it
    once), within [1, ``ceiling``]. Thread-safe."""

    def __init__(self, ceiling: float = DEFAULT_CEILING) -> None:
        self.ceiling = float(ceiling)
        self.value = self.ceiling
        self._cut_at = float("-inf")
        self._lock = threading.Lock()

    def allowed(self) -> int:
        """Runs that may be admitted at once now (at least 1)."""
        return max(1, int(self.value))

    def record(
        self, delivered: int, expected: int, window_s: float, now: float | None = None
    ) -> None:
        """One finished run: ``delivered`` iterations of the ``expected`` an idle machine gives
        its budget (``AnytimeRun.idle_iterations``)."""
        if expected <= 0:
            return
        now = time.perf_counter() if now is None else now
        with self._lock:
            if delivered >= DELIVERED_SHARE * expected:
                self.value = min(self.ceiling, self.value + 1.0 / self.value)
            elif now - self._cut_at >= window_s:
                self.value = max(1.0, self.value * DECREASE)
                self._cut_at = now

    def record_run(self, run: AnytimeRun) -> None:
        """A finished run's delivery (one the budget stopped before a step: starved); a
        cancelled or unfinished run says nothing."""
        if run.stopped_by in (None, "cancelled"):
            return
        if run.stopped_by in ("max_iterations", "converged"):
            expected = run.iteration  # it got what it asked for
        else:
            expected = run.idle_iterations()
        self.record(run.iteration, expected, run.plan.budget_ms / 1e3)


class Admission:
    """The runs admitted in one process, the work they still need, and how many at once the
    machine now serves in full (``delivery``). With ``shared`` (``itnet serve --workers N``),
    the runs and work the other processes on the machine admitted count as well, and this
    process's are published to them."""

    def __init__(self, retry_after_s: int = 1, ceiling: float = DEFAULT_CEILING,
                 shared: SharedWork | None = None) -> None:  # fmt: skip
        self.retry_after_s = retry_after_s
        self.delivery = DeliveryLimit(ceiling)
        self.shared = shared
        self._runs: list[AnytimeRun] = []
        self._lock = threading.Lock()

    @property
    def running(self) -> int:
        return len(self._runs)

    def own_ms(self) -> float:
        """The admitted runs' remaining needed work."""
        return sum(run.needed_work_ms() for run in self._runs)

    def _publish(self, own_ms: float) -> None:
        """This process's admitted runs and their needed work ``own_ms``, for the others."""
        if self.shared is not None:
            self.shared.publish(len(self._runs), own_ms)

    @contextmanager
    def admit(self, *runs: AnytimeRun) -> Iterator[None]:
        """Hold ``runs`` (one request's, e.g. an alignment's two clouds) among the admitted while
        they run; OverloadedError where they cannot fit together."""
        with self._lock:
            first = runs[0]
            others, others_ms = (0, 0.0) if self.shared is None else self.shared.others()
            running = len(self._runs) + others
            own = self.own_ms()
            # the work ahead of these runs, this process's and the others', over the step slots
            ahead = (own + others_ms) / max(1, first.model.concurrent_steps)
            cost = sum(run.needed_work_ms() for run in runs)
            if running and ahead + cost > min(run.left_ms() for run in runs):
                raise OverloadedError(
                    f"the server is busy: {running} estimate(s) need about {ahead:.0f} "
                    f"ms of steps, and this one about {cost:.0f} ms of its "
                    f"{first.plan.budget_ms:g} ms budget; retry in {self.retry_after_s} s",
                    self.retry_after_s,
                )
            if running and running + len(runs) > self.delivery.allowed():
                raise OverloadedError(
                    f"the server is busy: {running} estimate(s) running, and it serves "
                    f"about {self.delivery.allowed()} at once in full now; retry in "
                    f"{self.retry_after_s} s",
                    self.retry_after_s,
                )
            self._runs.extend(runs)
            self._publish(own + cost)
        try:
            yield
        finally:
            with self._lock:
                for run in runs:
                    self._runs.remove(run)
                self._publish(self.own_ms())
            if len(runs) == 1:  # a request's runs in turn (an alignment's) share one budget
                self.delivery.record_run(runs[0])
