"""Do two (or more) classifiers trained apart recognise more together? Each checkpoint's class
probabilities on the same fixed views (the trainer's: ``itnet classify-train``'s validation
views, or its test views), fused by averaging the log-probabilities as the service fuses
several looks (``service/recognition.py``); top-1 and mean class
accuracy of each member and of the fusion, the fusion's paired gain over the first member, and
how often the members agree. Torch checkpoints, so that a candidate is compared on validation
before anything is exported (export scores the test split).

    python -m benchmarks.classifier_ensemble itnet/models/classifier.pt runs/cls-seed1/itnet-2/best.pt
    python -m benchmarks.classifier_ensemble A.pt B.pt --split test   # once, after the choice

``--canonical-points K``: every member's transformer reads the first K of each view's (shuffled)
points, as the shipped graph is served (``itnet classify-export --canonical-points``), whatever
its checkpoint was trained with. ``--views V``: V views a shape (an even number: half occluded,
half the paper's) instead of the trainer's (2 for validation, 4 for test), fixed and cached
alike: more views, a smaller standard error. ``--baseline CKPT...``: the gains are paired
against these checkpoints fused (e.g. the shipped fusion, against one whose member trained
longer) instead of against the first checkpoint alone.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.metrics import paired_accuracy
from itnet.pose.recognition import mean_log_probability


def summary(scores: NDArray, labels: NDArray, baseline: NDArray) -> dict:
    """Scores (V, C) -> top-1 (+ paired gain over ``baseline``'s right/wrong per view) and mean
    class accuracy."""
    right = scores.argmax(1) == labels
    per_class = [right[labels == k].mean() for k in np.unique(labels)]
    return {
        **paired_accuracy(right, baseline),
        "mean_class": round(100 * float(np.mean(per_class)), 1),
    }


def main() -> None:
    import torch

    from itnet.model.classify.train import (
        ClassifyConfig,
        load_classifier,
        predict,
        run_splits,
        run_views,
    )

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", type=Path, nargs="+")
    parser.add_argument("--split", choices=["val", "test"], default="val")
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--canonical-points", type=int, default=None)
    parser.add_argument("--views", type=int, default=None, help="views a shape")
    parser.add_argument("--baseline", type=Path, nargs="+", default=None)
    args = parser.parse_args()
    if len(args.checkpoints) < 2:
        parser.error("give at least two checkpoints")

    torch.set_num_threads(args.threads)
    config = ClassifyConfig(data=args.data, cache=args.cache)  # the trainer's split and views
    if args.views is not None:
        config = config.model_copy(update={f"{args.split}_views": args.views})
    _, splits = run_splits(config)
    views, labels = run_views(config, splits, args.split)

    def scores(path: Path) -> NDArray:
        net = load_classifier(path)[0]
        if args.canonical_points is not None:
            net.config = replace(net.config, canonical_points=args.canonical_points)
        return predict(net, views)

    members = [scores(path) for path in args.checkpoints]
    first_class = members[0].argmax(1)
    first = first_class == labels
    if args.baseline is not None:
        known = dict(zip(args.checkpoints, members))
        baseline = mean_log_probability(
            [known[p] if p in known else scores(p) for p in args.baseline]
        )
        first = baseline.argmax(1) == labels
    result = {
        "baseline": [str(p) for p in args.baseline or args.checkpoints[:1]],
        "split": args.split,
        "canonical_points": args.canonical_points,
        "views": len(labels),
        "members": {
            str(path): summary(p, labels, first) for path, p in zip(args.checkpoints, members)
        },
        "fused": summary(mean_log_probability(members), labels, first),
        # how often each other member names the first one's class, averaged
        "agreement": round(
            100 * float(np.mean([(p.argmax(1) == first_class).mean() for p in members[1:]])), 1
        ),
    }
    print(json.dumps(result, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
