"""Training batches made ahead of the optimiser by worker processes.

On a GPU the network's step takes milliseconds and making a batch of fresh scans (numpy, one
core: ~25 ms for 32 scans, ~55 ms for 100) becomes the limit. ``Prefetcher`` runs the batch
function in forked workers, a bounded number of steps ahead, and hands the batches back in step
order. Each step's batch depends on its step number alone (the trainers seed a generator with
``[seed, step]``), so the batches are the same with any number of workers, and resume-exact.

Fork before the parent touches CUDA (create the ``Prefetcher`` before moving a network to the
GPU): the workers only run numpy on the data they inherit, which is why fork and not spawn (the
shapes are not pickled across).
"""

from __future__ import annotations

import multiprocessing
import signal
from collections import deque
from collections.abc import Callable, Iterator
from multiprocessing.pool import AsyncResult, Pool
from typing import Any

_MAKE: Callable[[int], Any] | None = None  # the batch function, inherited by forked workers


def _worker_start() -> None:
    """A worker dies on SIGTERM (``close`` terminates the pool) even where the parent had set a
    handler of its own, which fork hands down (a server's graceful-shutdown flag, say: with it
    the worker would wait on forever and ``close`` with it); Ctrl-C is the parent's to handle."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _make(step: int) -> Any:
    assert _MAKE is not None, "a Prefetcher's worker runs without its batch function"
    return _MAKE(step)


class Prefetcher:
    """``batches(start, stop)`` yields ``make(step)`` for each step in order, computed by
    ``workers`` forked processes up to ``ahead`` steps in advance (default ``2 × workers``);
    ``workers=0`` computes each batch in this process when asked. A context manager: leaving
    it stops the workers."""

    def __init__(self, make: Callable[[int], Any], workers: int = 0, ahead: int | None = None):
        global _MAKE
        if workers < 0:
            raise ValueError(f"workers must be >= 0, got {workers}")
        self.make, self.workers = make, workers
        self.ahead = max(1, ahead if ahead is not None else 2 * workers)
        self.pool: Pool | None = None
        if workers:
            _MAKE = make  # set before the fork: each worker inherits it
            self.pool = multiprocessing.get_context("fork").Pool(workers, _worker_start)

    def batches(self, start: int, stop: int) -> Iterator[Any]:
        if self.pool is None:
            if self.workers:
                raise RuntimeError("this Prefetcher is closed: its workers are gone")
            for step in range(start, stop):
                yield self.make(step)
            return
        pool, pending = self.pool, deque[AsyncResult]()  # closed later: "Pool not running"
        nxt = start
        while nxt < stop or pending:
            while nxt < stop and len(pending) < self.ahead:
                pending.append(pool.apply_async(_make, (nxt,)))
                nxt += 1
            yield pending.popleft().get()

    def close(self) -> None:
        if self.pool is not None:
            self.pool.terminate()
            self.pool.join()
            self.pool = None

    def __enter__(self) -> Prefetcher:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()
