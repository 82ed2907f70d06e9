"""Does a pose model fit its training shapes better than held-out ones? Over- or under-fitting.

Scores one model on views of ``--shapes`` training shapes and of as many validation shapes
(4 views each, the same scanner and seed for both), at 10 iterations:

    python -m benchmarks.fit_gap --model itnet/models/chair-fp32.onnx --scanner occluded

Training views far above validation: the model memorises shapes (more shapes or augmentation
help). About equal: it underfits (more steps, a larger batch or model help).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from itnet.model.categories import category
from itnet.model.data import cached_scan_set, load_shapes, split_files
from itnet.model.evaluate import anytime_poses, report
from itnet.model.scanner import VIEW_RULES, scan_config
from itnet.pose.runtime import load_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=Path("itnet/models/chair-fp32.onnx"))
    parser.add_argument("--scanner", default="occluded", choices=sorted(VIEW_RULES))
    parser.add_argument("--shapes", type=int, default=90, help="shapes of each split")
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    args = parser.parse_args()

    model = load_model(args.model, warm_up=False)
    cat = category(model.card.category, model.card.symmetry)
    files = split_files(args.data, cat.name, 0.1, 0)
    config = scan_config(VIEW_RULES[args.scanner])
    step = lambda x, p: model.step(x, p)[0]  # noqa: E731
    for split in ("train", "val"):
        shapes, _ = load_shapes(
            files[split][: args.shapes], "modelnet", args.cache, True, cat.quarter_turns,
            cat.symmetry,
        )  # fmt: skip
        scans = cached_scan_set(shapes, 4, 7, config, args.cache)
        rep = report(anytime_poses(step, scans, 10, model.card.points), scans, cat.symmetry)[0]
        acc = rep.accuracy[-1]
        print(
            f"{split:5s} {rep.scans} scans: {100 * acc:.1f} ± {100 * math.sqrt(acc * (1 - acc) / rep.scans):.1f} %"
            f"   rotation < 10°: {100 * rep.rotation_accuracy[-1]:.1f} %"
            f"   centre < 0.1 r: {100 * rep.translation_accuracy[-1]:.1f} %",
            flush=True,
        )


if __name__ == "__main__":
    main()
