"""Which validation shapes a pose model gets wrong in most of their views, and by which turn.

A network that misses a shape in nearly every view, always by the same half turn about up, is
telling something about that shape's label (its front is where the rest of the class has its
back) or about a real ambiguity of the category; misses spread over many shapes and axes are
the network's own. Prints, for each view rule, how the misses split (half turns about up,
quarter turns, other), and the shapes missed in at least ``--min-share`` of their views with
their median error and its axis. The test split is not touched::

    python -m benchmarks.shape_misses checkpoints/monitor.pt --category monitor
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import matrix_to_quat_wxyz, rotation_angle_deg
from itnet.symmetry import symmetry_group

AXES = "xyz"
DOMINANT = 0.8  # an axis is "x", "y" or "z" when that component of the unit axis exceeds this


def error_turns(
    estimate: ArrayLike, truth: ArrayLike, symmetry: str = "none"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rotations R_canonical_from_input (S, 3, 3) each -> the error left, ``R_est (S_g R_true)^T``
    with the symmetry turn S_g nearest the estimate, as (angles in degrees (S,), unit axes in the
    canonical frame (S, 3), sign-free: each component's absolute value)."""
    est = np.asarray(estimate, dtype=np.float64)
    true = np.asarray(truth, dtype=np.float64)
    group = symmetry_group(symmetry)  # (G, 3, 3): the samples the evaluation's error takes
    errors = est[:, None] @ np.swapaxes(group @ true[:, None], -1, -2)  # (S, G, 3, 3)
    angles = rotation_angle_deg(errors)  # (S, G)
    nearest = np.argmin(angles, axis=1)
    picked = errors[np.arange(len(est)), nearest]
    quat = matrix_to_quat_wxyz(picked)
    axes = np.abs(quat[:, 1:]) / np.maximum(
        np.linalg.norm(quat[:, 1:], axis=1, keepdims=True), 1e-12
    )
    return angles[np.arange(len(est)), nearest], axes


def turn_kind(angle_deg: float, axis: NDArray[np.float64]) -> str:
    """A missed scan's error rotation -> 'centre only' (under 10°), 'near miss' (10–20°), 'half
    turn about y', 'quarter turn about x', ..., or 'other'."""
    if angle_deg < 10:
        return "centre only"
    if angle_deg < 20:
        return "near miss"
    dominant = int(np.argmax(axis))
    if axis[dominant] < DOMINANT:
        return "other"
    if angle_deg >= 150:
        return f"half turn about {AXES[dominant]}"
    if 60 <= angle_deg < 120:
        return f"quarter turn about {AXES[dominant]}"
    return "other"


def by_shape(
    names: list[str], wrong: ArrayLike, angles: ArrayLike, axes: ArrayLike, min_share: float
) -> tuple[dict[str, int], list[dict]]:
    """Per scan: shape names (S,), missed (S,) bool, error angle (S,) and axis (S, 3) -> (how
    the misses split by ``turn_kind``, the shapes missed in at least ``min_share`` of their views,
    most missed first: shape, views, missed, median error of the missed views, their commonest
    turn kind and its count)."""
    wrong = np.asarray(wrong, dtype=bool)
    angles = np.asarray(angles, dtype=np.float64)
    axes = np.asarray(axes, dtype=np.float64)
    kinds = [turn_kind(a, x) if w else "" for a, x, w in zip(angles, axes, wrong)]
    split: dict[str, int] = defaultdict(int)
    for kind in kinds:
        if kind:
            split[kind] += 1
    scans: dict[str, list[int]] = defaultdict(list)
    for i, name in enumerate(names):
        scans[name].append(i)
    shapes = []
    for name, idx in scans.items():
        missed = [i for i in idx if wrong[i]]
        if not missed or len(missed) < min_share * len(idx):
            continue
        counts: dict[str, int] = defaultdict(int)
        for i in missed:
            counts[kinds[i]] += 1
        commonest = max(counts, key=lambda k: counts[k])
        shapes.append(
            {
                "shape": name,
                "views": len(idx),
                "missed": len(missed),
                "median_error_deg": round(float(np.median(angles[missed])), 1),
                "turn": commonest,
                "turn_views": counts[commonest],
            }
        )
    shapes.sort(key=lambda s: (-s["missed"] / s["views"], s["shape"]))
    return dict(sorted(split.items(), key=lambda kv: -kv[1])), shapes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--category", required=True)
    parser.add_argument("--scanners", nargs="+", default=["occluded", "paper"])
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument(
        "--min-share", type=float, default=0.75, help="list shapes missed this often"
    )
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--json", type=Path, default=None, help="also write the report here")
    args = parser.parse_args()
    import torch

    from benchmarks.validate_checkpoints import last_poses
    from itnet.metrics import is_correct, pose_errors

    torch.set_num_threads(2)
    report: dict = {"checkpoint": str(args.checkpoint), "category": args.category, "rules": {}}
    for scanner in args.scanners:
        poses, scans, cat = last_poses(args.checkpoint, args.category, scanner, args.views,
                                       args.iterations, args.data, args.cache)  # fmt: skip
        _, trans = pose_errors(poses, scans.poses, scans.radii)
        angles, axes = error_turns(poses[:, :3, :3], scans.poses[:, :3, :3], cat.symmetry)
        wrong = ~is_correct(angles, trans)
        split, shapes = by_shape(scans.names, wrong, angles, axes, args.min_share)
        report["rules"][scanner] = {"scans": len(wrong), "missed": int(wrong.sum()),
                                    "split": split, "shapes": shapes}  # fmt: skip
        print(f"{args.category} {scanner}: {int(wrong.sum())} of {len(wrong)} scans missed "
              f"({cat.symmetry}); by turn: {json.dumps(split)}")  # fmt: skip
        print(f"  shapes missed in at least {args.min_share:.0%} of their views: {len(shapes)} "
              f"of {len(set(scans.names))}")  # fmt: skip
        for s in shapes:
            print(f"  {s['shape']:22s} {s['missed']}/{s['views']}  median {s['median_error_deg']:5.1f}°"
                  f"  {s['turn'] or 'other'} ×{s['turn_views']}")  # fmt: skip
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
