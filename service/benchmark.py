"""Timing of one IT-Net step and of the anytime loop around it (onnxruntime, no torch)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

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
