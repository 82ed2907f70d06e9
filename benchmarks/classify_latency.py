"""What ``model: "auto"`` adds to a request: the time of ``itnet.pose.recognition.classify`` (check,
normalise, subsample to the card's points, run the classifier graph), in-process, onnxruntime
with the service's session options. The clouds: 16 box sides (2,000 points, in metres, no
category's), or with ``--scans N`` N partial scans of ModelNet10 test shapes (the classify
benchmarks' scanner), where how sure the classifier is shows (a cascade graph runs its other
heads only for unsure looks; the second opinion, ``--second-looks 4``, only for unsure clouds).

    python -m benchmarks.classify_latency [--model-dir itnet/models] [--runs 300] [--up] [--scans N]

``--up``: each request gives which way is up, so the upright classifier (where installed) runs
beside the other. ``--versus DIR``: another model folder's classifier on the same clouds, the two
alternating request by request, so that a machine whose speed drifts times both alike; also
prints the median of the per-pair ratio (this folder's time over DIR's). Prints the median, mean,
90th and 99th percentile in ms, the machine and the thread count. Run it on an otherwise idle
machine: other work on the same cores shows up in every percentile."""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np


def test_scans(count: int, data: Path) -> list[np.ndarray]:
    """``count`` partial scans (N, 3) of the test split's shapes, a seeded shape each."""
    from itnet.model.classify.data import class_names, load_splits, view_configs
    from itnet.model.scanner import scan_of

    shapes = load_splits(data, class_names(data), 0.1, 0, Path("cache"))["test"].shapes
    rng = np.random.default_rng(5)
    configs = view_configs()
    picks = rng.choice(len(shapes), count, replace=count > len(shapes))
    return [scan_of(shapes[k], rng, configs[i % len(configs)])[0] for i, k in enumerate(picks)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model-dir", type=Path, default=None)
    parser.add_argument("--runs", type=int, default=300)
    parser.add_argument("--points", type=int, default=2000, help="points of each test cloud")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--up", action="store_true", help="requests that give up")
    parser.add_argument("--looks", type=int, default=1)
    parser.add_argument(
        "--second-looks",
        type=int,
        default=1,
        help="the service's second opinion for unsure clouds (default 1: off, one look's time; "
        "these box-side clouds are no category's, so most would get it: benchmarks.classify_tta "
        "measures it on real views)",
    )
    parser.add_argument(
        "--versus", type=Path, default=None, help="a model folder to alternate with"
    )
    parser.add_argument(
        "--scans",
        type=int,
        default=0,
        help="time N partial scans of ModelNet10 test shapes (seeded, the classify benchmarks' "
        "scanner) instead of the box sides: a cascade graph's time depends on how sure its "
        "first head is, which box sides (no category) do not show",
    )
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    args = parser.parse_args()

    from itnet.pose.recognition import classify
    from itnet.pose.runtime import default_model_dir, load_all

    _, classifier = load_all(args.model_dir or default_model_dir(), threads=args.threads)
    other = None if args.versus is None else load_all(args.versus, threads=args.threads)[1]
    if classifier is None or (args.versus is not None and other is None):
        raise SystemExit("no classifier in the model folder")
    rng = np.random.default_rng(0)
    # a partial-scan-like cloud: one side of a box, in metres, off the origin; or views of real
    # objects (--scans), where how sure the classifier is counts
    clouds = (
        test_scans(args.scans, args.data)
        if args.scans
        else [
            rng.uniform(-1, 1, (args.points, 3)) * [0.4, 0.5, 0.05] + rng.normal(0, 2, 3)
            for _ in range(16)
        ]
    )
    up = [0.1, 1.0, 0.05] if args.up else None
    contenders = [classifier] if other is None else [classifier, other]
    for cloud in clouds[:4]:
        for each in contenders:
            classify(each, cloud, up=up, looks=args.looks, second_looks=args.second_looks)
    times: list[list[float]] = [[] for _ in contenders]
    upright, seconds = False, 0
    for i in range(args.runs):
        order = range(len(contenders)) if i % 2 else reversed(range(len(contenders)))
        for k in order:  # alternating which goes first
            start = time.perf_counter()
            recognition = classify(contenders[k], clouds[i % len(clouds)], up=up, looks=args.looks,
                                   second_looks=args.second_looks)  # fmt: skip
            times[k].append((time.perf_counter() - start) * 1e3)
            upright = upright or (k == 0 and recognition.upright)
            seconds += k == 0 and recognition.second_opinion
    p50, p90, p99 = np.percentile(times[0], [50, 90, 99])
    versus = {}
    if other is not None:
        mine, theirs = np.array(times[0]), np.array(times[1])
        versus = {
            "versus": str(args.versus),
            "versus_median_ms": round(float(np.median(theirs)), 3),
            "versus_mean_ms": round(float(np.mean(theirs)), 3),
            "versus_p90_ms": round(float(np.percentile(theirs, 90)), 3),
            "median_ratio": round(float(np.median(mine / theirs)), 3),
        }
    print(
        json.dumps(
            {
                "classifier": classifier.card.transformer,
                "precision": classifier.card.precision,
                "card_points": classifier.card.points,
                "cloud_points": args.points if not args.scans else "scans",
                "clouds": len(clouds),
                "up_given": args.up,
                "upright_classifier_ran": upright,
                "looks": args.looks,
                "second_looks": args.second_looks,
                "second_opinion_share": round(seconds / args.runs, 3),
                "runs": args.runs,
                "median_ms": round(float(p50), 3),
                "mean_ms": round(float(np.mean(times[0])), 3),
                "p90_ms": round(float(p90), 3),
                "p99_ms": round(float(p99), 3),
                **versus,
                "threads": args.threads,
                "machine": f"{platform.machine()} {os.cpu_count()} cores",
            }
        )
    )


if __name__ == "__main__":
    main()
