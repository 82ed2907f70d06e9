"""Two pose checkpoints of one category compared, scan by scan, on the validation views of each
named view rule (clean or by a depth camera): one run of 10 iterations each, fp32, no finishes:
the network's own accuracy, before the pipeline's finishing stages.

    python -m lab.studies.checkpoints_by_camera lab/weights/chair.pt runs/chair_sensor/best.pt \
        --views occluded occluded+kinect_v2 paper paper+kinect_v1

Prints, per view rule, each checkpoint's share right at (10 deg, 0.1 r) and the second's paired
gain over the first with its standard error. A fine-tune is kept where the camera views gain
and the clean ones lose no more than a standard error.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from itnet.metrics import is_correct, paired_accuracy
from itnet.model.categories import category
from itnet.model.category_set import validation_scans
from itnet.model.evaluate import anytime_poses, report, torch_step
from itnet.model.scanner import named_views
from itnet.model.train import load_checkpoint


def correct(checkpoint: Path, scans, symmetry: str) -> np.ndarray:  # type: ignore[no-untyped-def]
    net, state = load_checkpoint(checkpoint)
    poses = anytime_poses(torch_step(net), scans, 10, int(state["config"]["points"]))
    _, rot, trans = report(poses, scans, symmetry)
    return is_correct(rot[:, -1], trans[:, -1]).astype(float)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path)
    parser.add_argument("second", type=Path)
    parser.add_argument("--category", default="chair")
    parser.add_argument("--views", nargs="+", default=["occluded", "occluded+kinect_v2"])
    parser.add_argument("--per-shape", type=int, default=4, help="validation views per shape")
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    cat = category(args.category)
    out = {}
    for name in args.views:
        scans = validation_scans(args.data, cat, args.per_shape, scan=named_views(name, cat.name),
                                 cache=args.cache)  # fmt: skip
        a, b = (correct(c, scans, cat.symmetry) for c in (args.first, args.second))
        out[name] = {"first": round(100 * float(a.mean()), 1), **paired_accuracy(b, a)}
        print(name, out[name], flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
