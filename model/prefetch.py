"""Training batches made ahead of the optimiser by worker processes.

On a GPU the network's step takes milliseconds and making a batch of fresh scans (numpy, one
core: ~25 ms for 32 scans, ~55 ms for 100) becomes the limit. ``Prefetcher`` runs the batch
function in forked workers, a bounded number of steps ahead, and hands the batches back in step
order. Each step's batch depends on its step number alone (the trainers seed a generator with
``[seed, step]``), so the batches are the same with any number of workers, and resume-exact.

Fork before the parent touches CUDA (create the ``Prefetcher`` before moving a network to the
GPU): the workers only run numpy on the data they inherit, which is why fork and not spawn (the
shapes are not pickled across).

Each worker has a pipe of its own and nothing else shared with the parent: no pool threads, no
queue locks. ``multiprocessing.Pool`` had both, and its ``terminate`` waits on a lock an idle
worker holds; a pool left to the garbage collector was terminated from inside whatever code the
collector interrupted. Here stopping is ``SIGKILL`` and ``join``, safe from a finaliser too,
and a worker whose parent died exits on its own.
"""

from __future__ import annotations

import multiprocessing
import signal
import weakref
from collections import deque
from collections.abc import Callable, Iterator
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from typing import Any

_SIGNALS = {signal.SIGTERM, signal.SIGINT}


def _serve(make: Callable[[int], Any], conn: Connection, inherited: list[Connection]) -> None:
    """A worker: answer each step number with ``(True, make(step))`` or ``(False, error)``,
    until the parent sends ``None``, closes its end, or dies.

    It starts with SIGTERM and SIGINT blocked (see ``Prefetcher.__init__``): SIGTERM gets its
    default action back before they are unblocked, so a handler the parent had set (a server's
    graceful-shutdown flag, say) never runs here, however early the signal comes. Ctrl-C is the
    parent's to handle."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)
    for other in inherited:  # the parent's ends: with them open here, EOF would never come
        other.close()
    parent = multiprocessing.parent_process()
    watched: list[Any] = [conn] if parent is None else [conn, parent.sentinel]
    while True:
        if wait(watched) != [conn]:  # the parent is gone
            return
        try:
            step = conn.recv()
        except EOFError:
            return
        if step is None:
            return
        try:
            reply: tuple[bool, Any] = (True, make(step))
        except Exception as err:
            reply = (False, err)
        try:
            conn.send(reply)
        except OSError:  # the parent closed its end
            return
        except Exception as err:  # the batch or the error did not pickle: say what it was
            conn.send((False, RuntimeError(f"step {step}: {type(err).__name__}: {err}")))


def _stop(processes: list[BaseProcess], conns: list[Connection]) -> None:
    """Kill and reap the workers (also the finaliser of a Prefetcher never closed)."""
    for proc in processes:
        if proc.exitcode is None:
            proc.kill()
    for proc in processes:
        proc.join(10)
    for conn in conns:
        conn.close()


class Prefetcher:
    """``batches(start, stop)`` yields ``make(step)`` for each step in order, computed by
    ``workers`` forked processes up to ``ahead`` steps in advance (default ``2 × workers``);
    ``workers=0`` computes each batch in this process when asked. A context manager: leaving
    it stops the workers (and so does the garbage collector, for one never closed)."""

    def __init__(self, make: Callable[[int], Any], workers: int = 0, ahead: int | None = None):
        if workers < 0:
            raise ValueError(f"workers must be >= 0, got {workers}")
        self.make, self.workers = make, workers
        self.ahead = max(1, ahead if ahead is not None else 2 * workers)
        self.processes: list[BaseProcess] | None = None
        self._conns: list[Connection] = []
        self._unread: deque[Connection] = deque()  # replies asked for but never read
        if not workers:
            return
        context = multiprocessing.get_context("fork")
        processes: list[BaseProcess] = []
        # Blocked across the forks, so a worker cannot get SIGTERM before it has reset the
        # handler it inherits; the parent's signals wait the few milliseconds this takes.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
        try:
            for _ in range(workers):
                mine, theirs = context.Pipe()
                proc = context.Process(
                    target=_serve, args=(make, theirs, [*self._conns, mine]), daemon=True
                )
                proc.start()
                theirs.close()
                processes.append(proc)
                self._conns.append(mine)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            self._finalizer = weakref.finalize(self, _stop, processes, self._conns)
        self.processes = processes

    def batches(self, start: int, stop: int) -> Iterator[Any]:
        if self.workers == 0:
            for step in range(start, stop):
                yield self.make(step)
            return
        if self.processes is None:
            raise RuntimeError("this Prefetcher is closed: its workers are gone")
        while self._unread:  # a range left before its end: its replies are still coming
            self._receive(self._unread.popleft())
        pending = self._unread
        nxt = start
        while nxt < stop or pending:
            while nxt < stop and len(pending) < self.ahead:
                conn = self._conns[(nxt - start) % self.workers]
                conn.send(nxt)
                pending.append(conn)
                nxt += 1
            ok, value = self._receive(pending.popleft())
            if not ok:
                raise value
            yield value

    def _receive(self, conn: Connection) -> tuple[bool, Any]:
        try:
            reply: tuple[bool, Any] = conn.recv()
        except (EOFError, OSError):
            assert self.processes is not None
            codes = [proc.exitcode for proc in self.processes]
            raise RuntimeError(f"a prefetch worker died (exit codes {codes})") from None
        return reply

    def close(self) -> None:
        if self.processes is not None:
            self._finalizer()
            self.processes = None
            self._unread.clear()

    def __enter__(self) -> Prefetcher:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()
