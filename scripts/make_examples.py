"""Make the example clouds in itnet/examples/: two partial scans of one held-out object.

    .venv/bin/python scripts/make_examples.py
    .venv/bin/python scripts/make_examples.py --seed 39 --name chair_quarter   # a symmetric case
    .venv/bin/python scripts/make_examples.py --category table --radius 0.8 --name table \
        --shape ../shared/data/modelnet10/table/test/table_0400.pcd
    .venv/bin/python scripts/make_examples.py --category night_stand --radius 0.4 \
        --name night_stand --shape ../shared/data/modelnet10/night_stand/test/night_stand_0201.pcd

The object is a ModelNet10 *test* shape (never trained on), mapped to its category's canonical
frame (``itnet.model.shapes`` and the category's turn, ``itnet.model.categories``), given a real size (bounding-sphere radius ``--radius`` metres) and
scanned twice by the project's virtual depth camera (``itnet.model.scanner``) from seeded random
viewpoints. Each scan is in its own camera frame (metres), as a depth camera would deliver it.
Writes NAME_a.ply, NAME_b.ply (binary float32) and NAME_truth.json (the true T_b_from_a, both
true T_canonical_from_input and each scan's up direction, for checking ``itnet-align``'s
answer); NAME is ``--name``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from itnet.alignment.hypotheses import relative_pose
from itnet.cloud_io import write_ply
from itnet.geometry import rotation_error_deg
from itnet.model.categories import category
from itnet.model.scanner import ScanConfig, scan_shape
from itnet.model.shapes import load_shape

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    test_chairs = ROOT.parent / "shared/data/modelnet10/chair/test"
    parser.add_argument("--shape", type=Path, default=test_chairs / "chair_0894.pcd")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--radius", type=float, default=0.45, help="object size, metres")
    parser.add_argument("--min-angle", type=float, default=60.0, help="least view change, deg")
    parser.add_argument("--out", type=Path, default=ROOT / "itnet/examples")
    parser.add_argument("--name", default="chair", help="file name prefix")
    parser.add_argument("--category", default="chair", help="ModelNet10 class of --shape")
    args = parser.parse_args()

    shape = load_shape(args.shape, "modelnet", category(args.category).quarter_turns)
    rng = np.random.default_rng(args.seed)
    config = ScanConfig(outlier_fraction=(0.0, 0.0))
    cloud_a, pose_a = scan_shape(shape.points, rng, config)
    while True:  # a second view that differs enough to make the alignment worth doing
        cloud_b, pose_b = scan_shape(shape.points, rng, config)
        if float(rotation_error_deg(pose_a[:3, :3], pose_b[:3, :3])) >= args.min_angle:
            break
    for pose in (pose_a, pose_b):  # canonical units (radius 1) -> metres
        pose[:3, 3] *= args.radius
    cloud_a, cloud_b = cloud_a * args.radius, cloud_b * args.radius

    args.out.mkdir(parents=True, exist_ok=True)
    write_ply(args.out / f"{args.name}_a.ply", cloud_a)
    write_ply(args.out / f"{args.name}_b.ply", cloud_b)
    truth = {
        "source": f"ModelNet10 test shape {args.shape.name}, frame 'modelnet' -> canonical",
        "category": args.category,
        "seed": args.seed,
        "radius_m": args.radius,
        "points": [len(cloud_a), len(cloud_b)],
        "view_change_deg": round(float(rotation_error_deg(pose_a[:3, :3], pose_b[:3, :3])), 2),
        "T_b_from_a": relative_pose(pose_a, pose_b).tolist(),
        "T_canonical_from_a": pose_a.tolist(),
        "T_canonical_from_b": pose_b.tolist(),
        # which way is up in each scan (the canonical +y in its camera frame, R^T e_y): what a
        # level-sensing camera would give as ``--up-a`` / ``--up-b``
        "up_a": pose_a[1, :3].tolist(),
        "up_b": pose_b[1, :3].tolist(),
        "note": "canonical frame scaled to metres (bounding-sphere radius radius_m)",
    }
    (args.out / f"{args.name}_truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    print(f"wrote {args.out}: {len(cloud_a)} + {len(cloud_b)} points, views "
          f"{truth['view_change_deg']} deg apart")  # fmt: skip


if __name__ == "__main__":
    main()
