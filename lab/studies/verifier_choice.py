"""How well a category's learned verifier chooses among its runs, on the validation views of
each named view rule (clean or by a depth camera): the runs start from turned starts (stood up on
an up 2 degrees off where the card requires it) as the engine fuses them, and each scan's runs
are judged by the verifier as served.

    python -m lab.studies.verifier_choice night_stand --runs 4 \
        --views occluded occluded+kinect_v2 occluded+kinect_v2+crop

Prints, per view rule, the share of scans where some run's rotation is right (within 10
degrees: what a perfect choice would give), where the verifier's likeliest run is, where every
run is, and the share of runs right (what a choice at random gives); ``--verifier`` adds another
verifier's choice on the same runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from itnet.basin import canonical_points, likeliest_run
from itnet.model.categories import category
from itnet.model.category_set import validation_scans
from itnet.model.scanner import named_views
from itnet.model.verifier import UPRIGHT_UP_ERROR_DEG, pose_runs
from itnet.pose.runtime import LoadedVerifier, load_any, load_model

MODELS = Path(__file__).resolve().parents[2] / "itnet" / "models"
RIGHT_DEG = 10.0


def chosen_right(verifier: LoadedVerifier, points: np.ndarray, poses: np.ndarray,
                 right: np.ndarray) -> float:  # fmt: skip
    """Share of scans whose runs' points (S, K, N, 3) and poses (S, K, 4, 4) the verifier
    anchors on a right run (``right`` (S, K))."""
    picks = [likeliest_run(verifier.scores(canonical_points(p, t))) for p, t in zip(points, poses)]
    return float(right[np.arange(len(picks)), picks].mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("category")
    parser.add_argument("--views", nargs="+", default=["occluded", "occluded+kinect_v2"])
    parser.add_argument("--runs", type=int, default=4, help="runs a scan, from turned starts")
    parser.add_argument("--scans-per-shape", type=int, default=12)
    parser.add_argument("--verifier", type=Path, help="another verifier to compare (.onnx)")
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    args = parser.parse_args()

    model = load_model(MODELS / f"{args.category}.onnx")
    shipped = load_any(MODELS / f"{args.category}-verifier.onnx")
    other = load_any(args.verifier) if args.verifier else None
    if not isinstance(shipped, LoadedVerifier) or not isinstance(other, LoadedVerifier | None):
        parser.error("a verifier is an .onnx of itnet verifier-export")
    cat = category(args.category, model.card.symmetry)
    up_error = UPRIGHT_UP_ERROR_DEG if model.card.requires_up else None
    for rule in args.views:
        scans = validation_scans(args.data, cat, views=args.scans_per_shape,
                                 scan=named_views(rule, args.category), cache=args.cache)  # fmt: skip
        runs = pose_runs(model, scans, args.runs, model.card.points, seed=0, up_error_deg=up_error)
        right = runs.errors < RIGHT_DEG
        points = runs.points.astype(np.float32)
        line = (
            f"{rule}: {len(right)} scans, {args.runs} runs each; some run right "
            f"{right.any(1).mean():.1%}, the shipped verifier's choice "
            f"{chosen_right(shipped, points, runs.poses, right):.1%}"
        )
        if other is not None:
            line += f", {args.verifier.name}'s {chosen_right(other, points, runs.poses, right):.1%}"
        print(f"{line}, every run right {right.all(1).mean():.1%}, runs right {right.mean():.1%}")


if __name__ == "__main__":
    main()
