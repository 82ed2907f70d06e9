"""The anytime budget under concurrency: it counts from the request's arrival, a run waits for a
step slot only as long as its budget allows, and concurrent runs of a CPU-bound model keep their
budgets (the bug: all their steps ran at once, each slower than predicted, and overran)."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from hardening_helpers import live_server

from itnet.pose.runtime import LoadedModel, load_model
from itnet.service.settings import Settings
from tests.pose_runs import run_with

pytestmark = pytest.mark.timing  # every test here times a budget

# What a run may exceed its budget by: scheduling noise on a loaded 2-core machine, the final
# estimate's bookkeeping, and a step somewhat slower than its prediction.
MARGIN_MS = 15.0


def test_the_budget_counts_from_arrival(slow: LoadedModel, points: list) -> None:
    """A request that arrived 40 ms ago with 50 ms to spend cannot fit a 20 ms step."""
    run = run_with(slow, points, budget_ms=50, max_iterations=10,
                     started=time.perf_counter() - 0.040)  # fmt: skip
    assert run.run_to_end() is run.last
    assert (run.iteration, run.stopped_by) == (0, "budget")
    assert 40 <= run.elapsed_ms() < 60  # a step begun would have ended at 60 ms or later


def test_a_run_waits_for_a_step_slot_only_as_long_as_its_budget_allows(
    tiny: LoadedModel, slow_copy: Callable[..., Any], points: list
) -> None:
    model = slow_copy(tiny, delay_s=0.02, concurrent_steps=1)
    model.warm_up(runs=2)
    holding, release = threading.Event(), threading.Event()

    def hog() -> None:  # holds the model's only slot until released
        model.batcher.exclusive(lambda: (holding.set(), release.wait(5)), time.perf_counter() + 1)

    threading.Thread(target=hog).start()
    assert holding.wait(5)
    try:
        run = run_with(model, points, budget_ms=100, max_iterations=10)
        run.run_to_end()
    finally:
        release.set()
    assert (run.iteration, run.stopped_by) == (0, "budget")
    # It gave up when a step could no longer fit (at 80 ms), not at the end of the budget's wait
    # for the slot; a busy machine may wake the thread late, by up to the margin.
    assert 60 <= run.elapsed_ms() <= 100 + MARGIN_MS


def test_the_step_prediction_covers_scattered_steps_then_forgets_them(tiny: LoadedModel) -> None:
    """Two steps in twenty took 50 ms instead of 10: the next step is planned at 50 ms (the
    mean alone would let one run in ten overrun); two seconds later only the mean is left."""
    fresh, stale = (LoadedModel(tiny.card, tiny.path, tiny.session) for _ in range(2))
    for model, at in ((fresh, None), (stale, time.perf_counter() - 3.0)):
        for ms in [10.0] * 9 + [50.0] + [10.0] * 9 + [50.0]:
            model.record_step_ms(ms, at=at)
    assert fresh.step_ms < 20 and fresh.predicted_step_ms() == 50.0
    assert stale.predicted_step_ms() == stale.step_ms < 20


def overruns(model: LoadedModel, points: list, runs: int, budget_ms: float) -> list[float]:
    """``runs`` runs at once in threads; each one's elapsed time minus its budget, in ms."""

    def one(_: int) -> float:
        run = run_with(model, points, budget_ms=budget_ms, max_iterations=100,
                         converge=(0, 0))  # fmt: skip
        run.run_to_end()
        return run.elapsed_ms() - budget_ms

    with ThreadPoolExecutor(runs) as pool:
        return list(pool.map(one, range(runs)))


@pytest.mark.slow
def test_concurrent_cpu_bound_runs_keep_their_budgets(heavy_model_dir: Path, points: list) -> None:
    """Eight runs at once of a 10 ms CPU-bound step, one step slot per two cores: nine in ten
    end within the margin of their budget, and none later than two more steps. Without the step
    slots all eight step at once, each step takes several times its prediction, and most runs
    overrun by more than that. (A busy machine may steal one step's time from one run: that is
    the second bound, not the first.)"""
    from itnet.service.benchmark import time_step_ms

    model = load_model(heavy_model_dir / "tiny.onnx", threads=1, concurrent_steps=1)
    step_ms = time_step_ms(heavy_model_dir / "tiny.onnx", 1, len(points), 1, repeats=10)
    late = [ms for _ in range(3) for ms in overruns(model, points, runs=8, budget_ms=80)]
    assert np.percentile(late, 90) <= MARGIN_MS, sorted(late)[-5:]
    assert max(late) <= MARGIN_MS + 2 * step_ms, (sorted(late)[-5:], step_ms)


@pytest.mark.slow
def test_a_live_server_under_load_keeps_the_budget(
    heavy_model_dir: Path, settings: Settings, points: list
) -> None:
    """Twelve clients in closed loops for 2 s (or more) against 4 slots: every answer within
    budget plus the margin, the excess refused at once, nothing else. (The clients are coroutines of one
    thread: client threads would fight the server for this process's GIL.)"""
    from itnet.service.benchmark import time_step_ms

    model = load_model(heavy_model_dir / "tiny.onnx", threads=1, concurrent_steps=1)
    # Four requests share one step at a time: the budget must fit a few steps of this machine
    # (about 10 ms a step on a fast core, 25 ms on a slow one), or most answers run none.
    step_ms = time_step_ms(heavy_model_dir / "tiny.onnx", 1, len(points), 1, repeats=10)
    budget_ms = max(60.0, 8 * step_ms)
    request = {"points": points, "budget_ms": budget_ms, "max_iterations": 100}

    async def load(url: str) -> list[tuple[int, dict]]:
        replies: list[tuple[int, dict]] = []
        stop = time.perf_counter() + 2.0

        async def client(http: httpx.AsyncClient) -> None:
            while time.perf_counter() < stop:
                reply = await http.post("/v1/estimate", json=request)
                replies.append((reply.status_code, reply.json()))

        async with httpx.AsyncClient(base_url=url, timeout=10) as http:
            await asyncio.gather(*(client(http) for _ in range(12)))
        return replies

    # The suite's 0.5 s header and 1 s keep-alive timeouts are for the timeout tests: here a
    # client coroutine starved by the server's threads (same process) could meet them and see
    # its kept-alive connection closed, which is not what this test is about.
    relaxed = settings.server.model_copy(update={"header_timeout_s": 10.0, "keep_alive_s": 10})
    # Answers with no step meet any budget, so the load goes on (up to 6 s) until answers with
    # steps are enough to judge by: a busy machine can leave a 2 s window with almost none.
    replies: list[tuple[int, dict]] = []
    with live_server(settings.model_copy(update={"server": relaxed}), {"tiny": model}) as server:
        for _ in range(3):
            replies += asyncio.run(load(server.url))
            answered = [body for status, body in replies if status == 200]
            if len(answered) > 20 and sum(body["iterations"] for body in answered) > 20:
                break  # enough answers, and enough steps among them, to judge by
    statuses = {status for status, _ in replies}
    assert statuses <= {200, 503}, statuses
    elapsed = np.array([body["elapsed_ms"] for status, body in replies if status == 200])
    steps = sum(body["iterations"] for status, body in replies if status == 200)
    assert len(elapsed) > 20 and steps > 20, (len(elapsed), steps)
    # p90 within the margin; the rest of the tail is the machine's, not the service's (another
    # process on these two cores can take the CPU from any thread for tens of ms).
    assert np.percentile(elapsed, 90) <= budget_ms + MARGIN_MS, np.sort(elapsed)[-10:]
    assert elapsed.max() <= budget_ms + 4 * MARGIN_MS, np.sort(elapsed)[-10:]
