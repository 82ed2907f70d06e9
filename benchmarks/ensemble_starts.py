"""Where the ensemble mode's K runs should start, measured on the *validation* views.

Each rule runs K IT-Net runs per scan as the engine runs an ensemble (the whole cloud sets the
normalisation, each run gets its own random subset of ``min(points, 0.8 N)`` points, the K runs go
through each step as one batch of the served graph, ``itnet.fusion`` fuses them), 10 iterations,
no time limit, against one run of the card's point count on the same scans:

* ``subsets``: every run from the identity (the ensemble mode until session 14);
* ``turned``: from turns about z 360/K degrees apart (``geometry.viewing_axis_turns``, the mode now);
* ``turned+tilt20``: the same, every second start also tilted 20° about x (``itnet-align``'s).

    python -m benchmarks.ensemble_starts --model itnet/models/chair.onnx --ensemble 4

Prints, per kind of view, each rule's accuracy at (10°, 0.1 r) and its paired gain over the
single run with the standard error. Validation views only: the test split measures the choice
once (``benchmarks.bench_ensemble``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.fusion import fuse_poses
from itnet.geometry import viewing_axis_turns
from itnet.metrics import is_correct, paired_accuracy
from itnet.model.categories import category
from itnet.model.category_set import validation_scans
from itnet.model.evaluate import report, run_poses
from itnet.model.scanner import VIEW_RULES, scan_config
from itnet.pose.runtime import LoadedModel, load_model
from itnet.preprocess import (
    pose_from_normalized,
)


def start_rules(k: int) -> dict[str, NDArray | None]:
    """Rule name -> starting rotations (k, 3, 3); None: the single run."""
    return {
        "single": None,
        "subsets": np.tile(np.eye(3), (k, 1, 1)),
        "turned": viewing_axis_turns(k),
        "turned+tilt20": viewing_axis_turns(k, 20.0),
    }


def pose_of(model: LoadedModel, cloud: NDArray, starts: NDArray | None, seed: int) -> NDArray:
    """One scan (N, 3), input units -> the fused T_canonical_from_input (4, 4)."""
    pose, _, norm = run_poses(model, cloud, starts, seed)
    return pose_from_normalized(fuse_poses(pose, model.card.symmetry), norm)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=Path("itnet/models/chair.onnx"))
    parser.add_argument("--ensemble", type=int, default=4)
    parser.add_argument("--scanners", nargs="+", default=["occluded", "surface", "paper"])
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    args = parser.parse_args()

    model = load_model(args.model, warm_up=False)
    cat = category(model.card.category, model.card.symmetry)
    for scanner in args.scanners:
        config = scan_config(VIEW_RULES[scanner])
        scans = validation_scans(args.data, cat, scan=config, cache=args.cache)
        correct = {}
        for name, starts in start_rules(args.ensemble).items():
            poses = np.stack([pose_of(model, c, starts, i) for i, c in enumerate(scans.clouds)])
            _, rot, trans = report(poses[:, None], scans, cat.symmetry)
            correct[name] = is_correct(rot[:, -1], trans[:, -1]).astype(float)
        single = correct["single"]
        rows = {name: paired_accuracy(ok, single) for name, ok in correct.items()}
        cells = [
            f"{name} {r['accuracy']:.1f}% ({r['gain']:+.1f} ± {r['gain_stderr']:.1f})"
            for name, r in rows.items()
        ]
        print(f"{model.card.name} {scanner}, {len(single)} scans, K={args.ensemble}: "
              + "   ".join(cells), flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
