"""Checkpoints of one category side by side on its validation views: where a model is chosen.

Each checkpoint runs ``--iterations`` steps (torch, CPU) on the same fixed validation scans
(held-out training shapes, ``--views`` each) of every view rule asked for; prints the accuracy
at (10°, 0.1 r), symmetry-aware, and each one's paired gain over the first with its standard
error. The test split is not touched::

    python -m benchmarks.validate_checkpoints --category chair \
        itnet/models/chair.pt runs/gpu/chair/best.pt
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def last_poses(path: Path, category: str, scanner: str, views: int, iterations: int,
               data: Path, cache: Path):  # fmt: skip
    """A checkpoint's poses after ``iterations`` steps on a category's validation scans of one
    view rule -> (poses (S, 4, 4), the scans, the Category)."""
    from itnet.model.categories import category as category_of
    from itnet.model.category_set import validation_scans
    from itnet.model.evaluate import anytime_poses, torch_step
    from itnet.model.scanner import VIEW_RULES, scan_config
    from itnet.model.train import load_checkpoint

    net, state = load_checkpoint(path)
    cat = category_of(category)
    scans = validation_scans(
        data, cat, views=views, scan=scan_config(VIEW_RULES[scanner]), cache=cache
    )
    points = state.get("config", {}).get("points", 256)
    return anytime_poses(torch_step(net), scans, iterations, points)[:, -1], scans, cat


def correct_at_last(path: Path, category: str, scanner: str, views: int, iterations: int,
                    data: Path, cache: Path) -> np.ndarray:  # fmt: skip
    """(S,) 0/1 per validation scan at the last iteration."""
    from itnet.metrics import is_correct
    from itnet.model.evaluate import report

    poses, scans, cat = last_poses(path, category, scanner, views, iterations, data, cache)
    _, rot, trans = report(poses[:, None], scans, cat.symmetry)
    return is_correct(rot[:, -1], trans[:, -1]).astype(float)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", type=Path)
    parser.add_argument("--category", required=True)
    parser.add_argument("--scanners", nargs="+", default=["occluded", "paper"])
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--json", type=Path, default=None, help="also write the table here")
    args = parser.parse_args()
    import torch

    from itnet.metrics import paired_accuracy

    torch.set_num_threads(2)
    table: dict = {"category": args.category, "views": args.views, "rows": {}}
    for scanner in args.scanners:
        first = None
        for path in args.checkpoints:
            correct = correct_at_last(path, args.category, scanner, args.views,
                                             args.iterations, args.data, args.cache)  # fmt: skip
            first = correct if first is None else first
            row = paired_accuracy(correct, first)
            table["rows"].setdefault(str(path), {})[scanner] = row
            print(f"{args.category} {scanner:9s} {path!s:45s} {row['accuracy']:5.1f}% "
                  f"± {row['stderr']:.1f}  gain {row['gain']:+.1f} ± {row['gain_stderr']:.1f} "
                  f"({row['scans']} scans)", flush=True)  # fmt: skip
    if args.json is not None:
        args.json.write_text(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
