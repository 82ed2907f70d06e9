"""Poses a second when many clouds are in flight at once, their steps sharing graph calls.

    python -m benchmarks.throughput                                   # shipped models, CPU
    python -m benchmarks.throughput --in-flight 1,16,64 --clouds 512
    ITNET_PROVIDER=cuda python -m benchmarks.throughput --models lab/models --model chair-fp32

One process, one ``Catalog`` (``--provider``, default ``ITNET_PROVIDER`` or cpu; ``--batch-jobs``
steps a call may hold). For each ``--in-flight`` count, that many threads pose ``--clouds``
scans (the shipped examples, turned and moved at random) with the default request, and the
table says clouds a second, graph calls made, steps a call on average, and how far each pose is
from the one the same cloud gets alone (0 where calls are shared exactly; int8 graphs share no
call, see ``itnet/pose/step_batcher.py``).
"""

from __future__ import annotations

import os
import platform
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import typer

from itnet.cloud_io import read_cloud
from itnet.geometry import random_rotation
from itnet.pose.catalog import Catalog
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import RuntimeOptions, default_model_dir, load_all


def scans(count: int, seed: int = 0) -> list[np.ndarray]:
    """``count`` example scans (N, 3), each turned and moved at random."""
    examples = sorted((default_model_dir().parent / "examples").glob("*.ply"))
    clouds = [read_cloud(p) for p in examples]
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        cloud = clouds[i % len(clouds)]
        out.append(cloud @ random_rotation(rng).T + rng.normal(scale=0.5, size=3))
    return out


def main(
    in_flight: str = typer.Option("1,16", help="Clouds posed at once, one row each."),
    clouds: int = typer.Option(96, min=1, help="Clouds a row."),
    model: str = typer.Option("chair", help="Model name."),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped)."),
    provider: str = typer.Option(
        os.environ.get("ITNET_PROVIDER", "cpu"), help="cpu, cuda, tensorrt."
    ),
    batch_jobs: int = typer.Option(64, min=1, help="Steps one graph call may hold."),
    threads: int = typer.Option(2, min=1, help="onnxruntime threads."),
    budget_ms: float = typer.Option(1000.0, help="budget_ms of every request."),
) -> None:
    """Run the measurement and print its table."""
    options = RuntimeOptions(provider, batch_jobs)
    loaded, classifier = load_all(models or default_model_dir(), threads, True, 1, options)
    catalog = Catalog(loaded, classifier)
    pose_model = catalog.model(model)
    request = PoseRequest(model=model, budget_ms=budget_ms)
    work = scans(clouds)
    alone = [np.asarray(catalog.pose(c, request)["T_canonical_from_input"]) for c in work]
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"provider {provider}; model {model} ({pose_model.card.precision}); "
          f"{clouds} clouds; steps a call at most {pose_model.batcher.max_jobs}")  # fmt: skip
    print("| clouds in flight | clouds/s | graph calls | steps a call | largest pose difference |")
    print("|---|---|---|---|---|")
    for count in (int(v) for v in in_flight.split(",")):
        calls, jobs = pose_model.batcher.batches, pose_model.batcher.jobs
        start = time.perf_counter()
        with ThreadPoolExecutor(count) as pool:
            got = list(pool.map(lambda c: catalog.pose(c, request)["T_canonical_from_input"], work))
        seconds = time.perf_counter() - start
        calls, jobs = pose_model.batcher.batches - calls, pose_model.batcher.jobs - jobs
        worst = max(float(np.abs(np.asarray(g) - a).max()) for g, a in zip(got, alone))
        print(f"| {count} | {clouds / seconds:.1f} | {calls} | {jobs / max(calls, 1):.2f} | "
              f"{worst:.2g} |")  # fmt: skip


if __name__ == "__main__":
    typer.run(main)
