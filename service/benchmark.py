"""Timing of one IT-Net step, of the anytime loop around it, and of many requests posed at once
(onnxruntime, no torch)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.pose.catalog import Catalog
from itnet.pose.errors import OverloadedError
from itnet.pose.loop import AnytimeRun
from itnet.pose.plan import plan
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import load_model


def time_step_ms(path: Path, batch: int, points: int, threads: int, repeats: int = 200) -> float:
    """Median wall time of one session.run of the step graph, in ms (per call, not per item)."""
    model = load_model(path, threads=threads, warm_up=False)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(batch, points, 3)).astype(np.float32)
    pose = np.tile(np.eye(4, dtype=np.float32), (batch, 1, 1))
    for _ in range(10):
        model.step(x, pose)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        model.step(x, pose)
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3)


def loop_overhead(
    path: Path, threads: int, iterations: int = 20, repeats: int = 30
) -> dict[str, float]:
    """Per-iteration time inside AnytimeRun vs the raw step, on a cloud of the card's point count.

    One run (whatever the card's recommended ensemble: the raw step is one cloud's), held
    upright by +y where the card requires the up direction (as every request to it is). The
    iteration time is measured from the first to the last estimate (normalisation and
    resampling, done once per request, are reported apart as ``setup_ms``).
    """
    model = load_model(path, threads=threads)
    cloud = np.random.default_rng(1).normal(size=(model.card.points, 3))
    per_iteration, setup = [], []
    for _ in range(repeats):
        request = PoseRequest(
            budget_ms=10_000,
            max_iterations=iterations,
            ensemble=1,
            up=[0.0, 1.0, 0.0] if model.card.requires_up else None,
        )
        run = AnytimeRun(plan(model, request), cloud)
        setup.append(run.elapsed_ms())
        estimates = list(run)
        first, last = estimates[0], estimates[-1]
        per_iteration.append((last.elapsed_ms - first.elapsed_ms) / (len(estimates) - 1))
    raw = time_step_ms(path, 1, model.card.points, threads)
    loop = float(np.median(per_iteration))
    return {
        "raw_step_ms": raw,
        "loop_iteration_ms": loop,
        "overhead_pct": 100 * (loop / raw - 1),
        "setup_ms": float(np.median(setup)),
    }


GOOD_ITERATIONS = 5  # a reply with fewer steps is a pose, but a poor one


def concurrent_poses(
    catalog: Catalog, request: PoseRequest, cloud: NDArray, clients: int, duration_s: float
) -> dict[str, float]:
    """``clients`` threads, each posing ``cloud`` with ``request`` (its ``model`` named) by
    ``Catalog.pose`` and asking again as soon as its pose is back (after a refusal, when its
    ``retry_after_s`` has passed, as the service's clients honour ``Retry-After``), for
    ``duration_s`` -> replies a second, replies with at least ``GOOD_ITERATIONS`` steps a second,
    iterations a reply (mean), requests refused (the catalog's admission by work, or no step in
    the budget: the service's 503), graph calls made and steps a call on average."""
    batcher = catalog.model(request.model).batcher
    calls, jobs = batcher.batches, batcher.jobs
    stop = time.perf_counter() + duration_s
    lock = threading.Lock()
    iterations: list[int] = []
    refused = 0

    def client() -> None:
        nonlocal refused
        while time.perf_counter() < stop:
            try:
                steps = int(catalog.pose(cloud, request)["iterations"])
            except OverloadedError as err:
                with lock:
                    refused += 1
                time.sleep(max(0.0, min(err.retry_after_s, stop - time.perf_counter())))
                continue
            with lock:
                iterations.append(steps)

    started = time.perf_counter()
    workers = [threading.Thread(target=client) for _ in range(clients)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    seconds = time.perf_counter() - started
    calls, jobs = batcher.batches - calls, batcher.jobs - jobs
    return {
        "clients": clients,
        "replies_per_s": len(iterations) / seconds,
        "good_per_s": sum(i >= GOOD_ITERATIONS for i in iterations) / seconds,
        "iterations_mean": float(np.mean(iterations)) if iterations else 0.0,
        "refused": refused,
        "calls": calls,
        "steps_a_call": jobs / max(calls, 1),
    }
