"""model/prefetch.py: batches made ahead by forked workers come back in step order, the same as
made in this process; errors reach the parent; closing stops the workers at once."""

from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from itnet.model.prefetch import Prefetcher


def _batch(step: int) -> np.ndarray:
    """A batch that depends on its step alone, as the trainers' are."""
    return np.random.default_rng([0, step]).normal(size=(4, 3))


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_workers_give_the_same_batches_in_step_order(workers: int) -> None:
    expected = [_batch(step) for step in range(3, 10)]
    with Prefetcher(_batch, workers=0) as here:
        made_here = list(here.batches(3, 10))
    with Prefetcher(_batch, workers=workers) as ahead:
        made_ahead = list(ahead.batches(3, 10))
    assert len(made_here) == len(made_ahead) == 7
    for want, a, b in zip(expected, made_here, made_ahead):
        np.testing.assert_array_equal(a, want)
        np.testing.assert_array_equal(b, want)


def test_batches_are_made_in_worker_processes_only_when_asked() -> None:
    def whose(step: int) -> tuple[int, int]:
        return step, os.getpid()

    with Prefetcher(whose, workers=0) as here:
        assert here.processes is None
        assert list(here.batches(0, 4)) == [(s, os.getpid()) for s in range(4)]
    with Prefetcher(whose, workers=2) as ahead:
        got = list(ahead.batches(0, 6))
    assert [s for s, _ in got] == list(range(6))
    assert os.getpid() not in {pid for _, pid in got}


def test_empty_range_and_a_range_in_pieces() -> None:
    with Prefetcher(_batch, workers=2) as p:
        assert list(p.batches(5, 5)) == []
        first, second = list(p.batches(0, 3)), list(p.batches(3, 6))  # the workers are reused
    for step, batch in enumerate(first + second):
        np.testing.assert_array_equal(batch, _batch(step))


def test_negative_worker_count_is_rejected() -> None:
    with pytest.raises(ValueError, match="workers"):
        Prefetcher(_batch, workers=-1)


def test_default_lookahead() -> None:
    with Prefetcher(_batch, workers=0) as here, Prefetcher(_batch, workers=3) as ahead:
        assert here.ahead == 1
        assert ahead.ahead == 6
    with Prefetcher(_batch, workers=2, ahead=0) as p:
        assert p.ahead == 1  # at least one


def test_workers_stay_at_most_ahead_steps_ahead(tmp_path: Path) -> None:
    def make(step: int) -> int:
        (tmp_path / str(step)).touch()  # the workers share the parent's file system
        return step

    with Prefetcher(make, workers=2, ahead=3) as p:
        batches = p.batches(0, 50)
        assert next(batches) == 0
        time.sleep(0.5)  # time for any batch already asked of the workers to be made
        made = sorted(int(f.name) for f in tmp_path.iterdir())
        assert made == list(range(len(made))) and 1 <= len(made) <= 3
        assert list(batches) == list(range(1, 50))


def test_close_stops_the_workers() -> None:
    p = Prefetcher(_batch, workers=2)
    try:
        assert p.processes is not None
        workers = list(p.processes)
        assert len(workers) == 2 and all(w.is_alive() for w in workers)
        p.close()
        assert p.processes is None
        assert not any(w.is_alive() for w in workers)
        p.close()  # a second close does nothing
        assert p.processes is None
        with pytest.raises(RuntimeError, match="closed"):
            next(p.batches(0, 1))
    finally:
        p.close()


def test_leaving_the_context_closes_it() -> None:
    with Prefetcher(_batch, workers=2) as p:
        assert p.processes is not None
        workers = list(p.processes)
        next(p.batches(0, 10))
    assert p.processes is None
    assert not any(w.is_alive() for w in workers)


def test_a_prefetcher_never_closed_stops_its_workers_when_collected() -> None:
    p = Prefetcher(_batch, workers=2)
    assert p.processes is not None
    workers = list(p.processes)
    del p
    gc.collect()
    assert not any(w.is_alive() for w in workers)


def test_a_range_left_early_does_not_leak_into_the_next() -> None:
    """Replies already asked for when a range is abandoned are read and dropped, not handed
    out as the next range's batches."""
    with Prefetcher(_batch, workers=2, ahead=4) as p:
        first = p.batches(0, 20)
        assert next(first) is not None
        first.close()
        again = list(p.batches(30, 34))
    for step, batch in zip(range(30, 34), again):
        np.testing.assert_array_equal(batch, _batch(step))


def test_a_worker_killed_from_outside_is_an_error_not_a_hang() -> None:
    def slow(step: int) -> int:
        time.sleep(0.05)
        return step

    with Prefetcher(slow, workers=2) as p:
        assert p.processes is not None
        batches = p.batches(0, 100)
        assert next(batches) == 0
        os.kill(p.processes[1].pid or 0, signal.SIGKILL)
        with pytest.raises(RuntimeError, match="worker died"):
            list(batches)


def test_workers_exit_when_their_parent_dies(tmp_path: Path) -> None:
    """A parent killed outright (no close, no finaliser) leaves no workers behind."""
    script = tmp_path / "parent.py"
    script.write_text(
        "import os, sys\n"
        "from itnet.model.prefetch import Prefetcher\n"
        "p = Prefetcher(abs, workers=2)\n"
        "print(*[w.pid for w in p.processes], flush=True)\n"
        "os.kill(os.getpid(), 9)\n"
    )
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    pids = [int(pid) for pid in run.stdout.split()]
    assert len(pids) == 2, run.stderr
    deadline = time.monotonic() + 10
    while any(_alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(pid) for pid in pids)


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (orphans are reaped by init; a zombie counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def test_an_error_in_a_worker_reaches_the_parent_at_its_batch() -> None:
    def make(step: int) -> int:
        if step == 3:
            raise RuntimeError(f"no batch for step {step}")
        return step

    got: list[int] = []
    with Prefetcher(make, workers=2) as p, pytest.raises(RuntimeError, match="no batch for step 3"):
        for batch in p.batches(0, 10):
            got.append(batch)
    assert got == [0, 1, 2]  # the batches before it were handed over first
    assert p.processes is None


def test_stopping_early_returns_promptly() -> None:
    def slow(step: int) -> int:
        time.sleep(0.2)  # all 100 batches would take 10 s on two workers
        return step

    started = time.perf_counter()
    p = Prefetcher(slow, workers=2)
    batches = p.batches(0, 100)
    assert [next(batches), next(batches)] == [0, 1]
    p.close()
    assert time.perf_counter() - started < 3.0
    assert p.processes is None


def _sigterm_is_default(step: int) -> bool:
    return signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


def test_workers_die_on_sigterm_whatever_the_parent_set_however_early() -> None:
    """A SIGTERM handler the parent set (a server's graceful-shutdown flag) is handed down by
    fork; a worker that ran it would live on. The workers put the default back, with the signal
    blocked across the fork, so even a SIGTERM sent the moment they start ends them; the
    parent's own mask is as it was."""
    previous = signal.signal(signal.SIGTERM, lambda *_: None)  # catch it, do not exit
    try:
        for _ in range(5):
            p = Prefetcher(_sigterm_is_default, workers=2)
            try:
                assert p.processes is not None
                for worker in p.processes:
                    worker.terminate()
                for worker in p.processes:
                    worker.join(10)
                assert [w.exitcode for w in p.processes] == [-signal.SIGTERM] * 2
            finally:
                p.close()
        with Prefetcher(_sigterm_is_default, workers=2) as p:
            assert list(p.batches(0, 4)) == [True] * 4
        assert signal.SIGTERM not in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    finally:
        signal.signal(signal.SIGTERM, previous)
