"""The steps of every run in flight on one model, batched into one onnxruntime call.

A run that wants a step submits its points (B, N, 3) and poses (B, 4, 4) with the latest time the
step may end to keep the run inside its budget. A model runs at most ``slots`` calls at once
(more would share the cores and each would take longer than predicted). The thread whose job
finds a slot free leads: it runs a batch of every queued job that fits, earliest deadline first,
hands each its rows of the output, and passes the lead to a waiting job when its own is done.
While a batch runs, new jobs queue; the next batch takes them together. No job waits for company:
a lone job runs at once, and the batch size and the wait are bounded by the jobs' own deadlines
(a job joins a batch only where the batch's predicted time still ends before its deadline; one
that cannot finish in time even alone is turned away, and its run stops by the budget).

Points of different counts are padded to the largest by repeating each job's last point: one
IT-Net step max-pools over the points, so a repeated point changes nothing. A job may also be a
piece of work that needs a slot to itself (``work``: the verify probes); it runs alone.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

StepFn = Callable[[NDArray[np.float32], NDArray[np.float32]], tuple[NDArray, NDArray]]
PredictFn = Callable[[int, int], float]  # (runs, points) -> ms


@dataclass(eq=False)
class _Job:
    points: NDArray[np.float32] | None  # (B, N, 3); None for a piece of work
    poses: NDArray[np.float32] | None  # (B, 4, 4)
    latest: float  # time.perf_counter() by which it must end
    work: Callable[[], Any] | None = None
    result: Any = None
    error: BaseException | None = None
    state: str = "waiting"  # waiting -> taken -> done; or gone (turned away, or gave up)
    lead: bool = False  # leads (found a slot free, or was handed the lead)

    @property
    def runs(self) -> int:
        return 0 if self.points is None else len(self.points)

    @property
    def size(self) -> int:
        return 0 if self.points is None else self.points.shape[1]


class StepBatcher:
    """Batches the steps of one model. ``step``: one graph call (points, poses) -> (poses_next,
    delta); ``predict_ms(runs, points)``: a call's predicted time; ``slots``: calls at once;
    ``max_jobs``: jobs a batch may hold (1: no batching across runs); ``record(ms, runs,
    points)``: told each call's measured time."""

    def __init__(self, step: StepFn, predict_ms: PredictFn, slots: int = 1, max_jobs: int = 64,
                 record: Callable[[float, int, int], None] | None = None) -> None:  # fmt: skip
        if slots < 1 or max_jobs < 1:
            raise ValueError(f"need at least one slot and one job a batch ({slots}, {max_jobs})")
        self._step, self._predict, self._record = step, predict_ms, record
        self.slots, self.max_jobs = slots, max_jobs
        self._cond = threading.Condition()
        self._queue: list[_Job] = []
        self._busy = 0  # slots held by leaders
        self.batches = 0  # calls made, and the jobs they served (for the metrics and tests)
        self.jobs = 0

    def step(
        self, points: NDArray[np.float32], poses: NDArray[np.float32], latest: float
    ) -> tuple[NDArray, NDArray] | None:
        """One step of ``points`` (B, N, 3) from ``poses`` (B, 4, 4), ending by ``latest`` (a
        ``time.perf_counter()`` value) -> (poses_next, delta), each (B, 4, 4); None where it
        cannot end in time."""
        job = self._submit(_Job(points, poses, latest))
        return None if job.state == "gone" else job.result

    def exclusive(self, work: Callable[[], Any], latest: float) -> tuple[bool, Any]:
        """``work()`` with a slot to itself, started in deadline order -> (True, its result), or
        (False, None) where the slot does not come before ``latest``."""
        job = self._submit(_Job(None, None, latest, work))
        return (False, None) if job.state == "gone" else (True, job.result)

    @property
    def waiting(self) -> int:
        with self._cond:
            return len(self._queue)

    def _submit(self, job: _Job) -> _Job:
        with self._cond:
            self._queue.append(job)
            if self._busy < self.slots:
                self._busy += 1
                job.lead = True
            while not job.lead and job.state in ("waiting", "taken"):
                left = job.latest - time.perf_counter()
                if job.state == "waiting" and left <= 0:  # never taken in time: give up
                    self._queue.remove(job)
                    job.state = "gone"
                    break
                self._cond.wait(left if job.state == "waiting" else None)
        if job.lead:
            self._lead(job)
        if job.error is not None:
            raise job.error
        return job

    def _lead(self, own: _Job) -> None:
        """Run batches until ``own`` is done (or turned away), then pass the lead on."""
        while own.state in ("waiting", "taken"):
            with self._cond:
                if own.state == "taken":  # in another leader's call (several slots): wait
                    self._cond.wait()
                    continue
                batch = self._take()
            if batch:
                self._run(batch)
        with self._cond:
            waiting = [j for j in self._queue if j.state == "waiting"]
            if waiting:
                min(waiting, key=lambda j: j.latest).lead = True
                self._cond.notify_all()
            else:
                self._busy -= 1

    def _take(self) -> list[_Job]:
        """(Under the lock.) The next batch: queued jobs earliest deadline first, each joining
        where the batch's predicted time still ends before every member's deadline; a job that
        cannot end in time alone is turned away. A piece of work goes alone."""
        now = time.perf_counter()
        batch: list[_Job] = []
        runs, size = 0, 0
        for job in sorted(self._queue, key=lambda j: j.latest):
            if job.work is not None:
                if not batch:
                    batch = [job]
                break
            if now + self._predict(job.runs, job.size) / 1e3 > job.latest:
                self._queue.remove(job)
                job.state = "gone"
                self._cond.notify_all()
                continue
            ends = now + self._predict(runs + job.runs, max(size, job.size)) / 1e3
            if batch and (len(batch) >= self.max_jobs or ends > min(j.latest for j in batch)
                          or ends > job.latest):  # fmt: skip
                continue
            batch.append(job)
            runs, size = runs + job.runs, max(size, job.size)
        for job in batch:
            self._queue.remove(job)
            job.state = "taken"
        return batch

    def _run(self, batch: list[_Job]) -> None:
        """One call for the batch (outside the lock); each job gets its rows and is woken."""
        try:
            if batch[0].work is not None:
                batch[0].result = batch[0].work()
            else:
                size = max(job.size for job in batch)
                points = np.concatenate([_padded(job.points, size) for job in batch])
                poses = np.concatenate([job.poses for job in batch])
                start = time.perf_counter()
                out, delta = self._step(points, poses)
                if self._record is not None:
                    self._record((time.perf_counter() - start) * 1e3, len(points), size)
                row = 0
                for job in batch:
                    job.result = (out[row : row + job.runs], delta[row : row + job.runs])
                    row += job.runs
        except BaseException as err:  # every member learns of it, not only the leader
            for job in batch:
                job.error = err
        with self._cond:
            self.batches += 1
            self.jobs += len(batch)
            for job in batch:
                job.state = "done"
            self._cond.notify_all()


def _padded(points: NDArray[np.float32] | None, size: int) -> NDArray[np.float32]:
    """(B, N, 3) -> (B, size, 3), the last point repeated (a max-pool ignores repeats)."""
    assert points is not None
    if points.shape[1] == size:
        return points
    extra = np.repeat(points[:, -1:], size - points.shape[1], axis=1)
    return np.concatenate([points, extra], axis=1)
