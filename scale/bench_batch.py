"""Throughput of ``itnet batch pose`` with 1 and 2 workers (clouds per second).

    python -m itnet.scale.bench_batch --clouds 1000 --runs 1x1 1x2 2x1   # workers x threads

Makes ``--clouds`` example clouds in a temporary folder (the shipped example scans, each turned
by a random rotation and moved), runs the batch on them once per worker count (a fresh output
each time, Ray started and stopped each time), checks that every run wrote the same poses, and
prints a markdown table: clouds per second over the whole run (Ray's start and the models'
loading included) and steady (after the first batch came back), and the speed-up over the first
worker count.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
from pathlib import Path

import numpy as np


def make_clouds(folder: Path, count: int, seed: int = 0) -> list[str]:
    """``count`` .ply files: the shipped example scans turned and moved at random."""
    from itnet.cloud_io import read_cloud, write_ply
    from itnet.geometry import axis_angle_to_matrix
    from itnet.pose.runtime import default_model_dir

    examples = sorted((default_model_dir().parent / "examples").glob("*.ply"))
    clouds = [read_cloud(p) for p in examples]
    rng = np.random.default_rng(seed)
    paths = []
    for i in range(count):
        axis = rng.normal(size=3)
        turn = axis_angle_to_matrix(axis / np.linalg.norm(axis), rng.uniform(0, np.pi))
        path = folder / f"cloud_{i:05d}.ply"
        write_ply(path, clouds[i % len(clouds)] @ turn.T + rng.normal(size=3))
        paths.append(str(path))
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clouds", type=int, default=1000)
    parser.add_argument("--runs", nargs="+", default=["1x1", "1x2", "2x1"],
                        help="WORKERSxTHREADS each; speed-ups are against the first")  # fmt: skip
    parser.add_argument("--batch-size", type=int, default=32)
    args = parser.parse_args()

    import pyarrow.parquet as pq

    from itnet.scale.batch import run_batch
    from itnet.scale.table import BatchTable
    from itnet.scale.workers import PoseWorker

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}; {args.clouds} clouds, batch {args.batch_size}")  # fmt: skip
    print(
        "| workers | threads each | clouds/s (whole run) | clouds/s (steady) | speed-up (steady) |"
    )
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        items = [{"file": f} for f in make_clouds(Path(tmp), args.clouds)]
        first, poses = 0.0, None
        for run in args.runs:
            workers, threads = (int(v) for v in run.split("x"))
            out = Path(tmp) / f"poses_{run}.parquet"
            worker_args = {"model": "chair", "model_dir": None,
                           "request": {"budget_ms": 1000.0}}  # fmt: skip
            stats = run_batch(PoseWorker, worker_args, items, BatchTable(out, ("file",)),
                              ("file",), workers, None, threads, args.batch_size,
                              progress=False)  # fmt: skip
            table = pq.read_table(out).sort_by("file")
            got = np.array(table["T_canonical_from_input"].to_pylist())
            if poses is not None and not np.allclose(got, poses, atol=1e-6):
                raise SystemExit(f"run {run} wrote other poses than run {args.runs[0]}")
            poses = got
            first = first or stats.steady_per_second
            print(f"| {workers} | {threads} | {args.clouds / stats.seconds:.1f} | "
                  f"{stats.steady_per_second:.1f} | {stats.steady_per_second / first:.2f}x |")  # fmt: skip


if __name__ == "__main__":
    main()
