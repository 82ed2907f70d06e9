"""Earliest-deadline-first step slots (itnet/pose/step_slots.py)."""

from __future__ import annotations

import threading
import time

import pytest

from itnet.pose.step_slots import StepSlots


def _wait_until(condition, timeout_s: float = 5.0) -> None:  # type: ignore[no-untyped-def]
    end = time.perf_counter() + timeout_s
    while not condition():
        assert time.perf_counter() < end, "timed out"
        time.sleep(0.001)


def test_a_freed_slot_goes_to_the_earliest_deadline_not_the_first_caller() -> None:
    slots = StepSlots(1)
    assert slots.acquire(deadline=0.0, timeout_s=0)
    order: list[int] = []

    def waiter(deadline: int) -> None:
        assert slots.acquire(deadline=float(deadline), timeout_s=5)
        order.append(deadline)
        slots.release()

    threads = []
    for deadline in (3, 1, 2):  # arrive in this order
        threads.append(threading.Thread(target=waiter, args=(deadline,)))
        threads[-1].start()
        _wait_until(lambda n=len(threads): slots.waiting == n)
    slots.release()
    for t in threads:
        t.join(5)
    assert order == [1, 2, 3]


def test_a_releasing_run_cannot_take_the_slot_back_from_a_waiter() -> None:
    slots = StepSlots(1)
    assert slots.acquire(deadline=0.0, timeout_s=0)
    got = threading.Event()

    def waiter() -> None:
        if slots.acquire(deadline=10.0, timeout_s=5):
            got.set()
            time.sleep(0.05)
            slots.release()

    thread = threading.Thread(target=waiter)
    thread.start()
    _wait_until(lambda: slots.waiting == 1)
    slots.release()
    assert not slots.acquire(deadline=1.0, timeout_s=0)  # the waiter was granted it
    assert got.wait(5)
    thread.join(5)
    assert slots.acquire(deadline=1.0, timeout_s=0)  # and it came back when the waiter was done


def test_a_timed_out_waiter_leaves_no_trace() -> None:
    slots = StepSlots(1)
    assert slots.acquire(deadline=0.0, timeout_s=0)
    start = time.perf_counter()
    assert not slots.acquire(deadline=1.0, timeout_s=0.05)
    assert 0.04 <= time.perf_counter() - start < 1.0
    assert slots.waiting == 0
    slots.release()  # goes back to the pool, not to the departed waiter
    assert slots.acquire(deadline=2.0, timeout_s=0)
    assert not slots.acquire(deadline=3.0, timeout_s=0)


def test_several_slots_and_bad_counts() -> None:
    slots = StepSlots(2)
    assert slots.acquire(0.0, 0) and slots.acquire(0.0, 0)
    assert not slots.acquire(0.0, 0)
    with pytest.raises(ValueError, match="at least one slot"):
        StepSlots(0)
