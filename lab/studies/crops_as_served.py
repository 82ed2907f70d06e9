"""Crops cut out of a room, named as ``itnet classify crop.ply --units m --up x,y,z`` names them:
the floor and walls a crop keeps taken away (``itnet.floor_and_walls``), then the classifiers
with up and the size prior, in metres. Two settings compared view by view on the same crops.

    python -m lab.studies.crops_as_served --split val --compare floor-either-end
    python -m lab.studies.crops_as_served --split val --models-a DIR --models-b DIR2

Each view is a Kinect v2 scan of a shape of the split at its category's real size (a radius
drawn from ``itnet.model.categories.REAL_RADIUS_M``), with the surroundings a crop keeps
(``model.surroundings``: floor, wall, a neighbour), in the camera's
frame and metres; up is the truth tilted 2 degrees. ``--compare floor-either-end`` takes the
floor away where it runs on past the object at either end (the served rule asks both ends of one
direction along it); ``--models-b`` names the crops with another folder's classifiers. Prints
top-1 (or, with ``--pose``, the share posed right by the class's own model) of each setting per
view rule and per class, and the paired gain with its standard error.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

import itnet.floor_and_walls as floor_and_walls
from itnet.geometry import invert_rigid
from itnet.metrics import is_correct, paired_accuracy, pose_errors
from itnet.model.categories import category, real_radius_m
from itnet.model.classify.data import class_names, load_splits
from itnet.model.scanner import named_views, scan_shape
from itnet.model.shapes import yaw_rotation
from itnet.pose.cloud import Limits, cut_out
from itnet.pose.recognition import classify
from itnet.pose.request import PoseRequest
from itnet.symmetry import symmetric_rotation_error_deg

RULES = ("occluded+kinect_v2+crop", "paper+kinect_v2+crop")
UP_ERROR_DEG = 2.0


View = tuple[str, str, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]


def crops(split: str, per_class: int, seed: int, data: Path, cache: Path) -> list[View]:
    """(rule, class, camera-frame crop in metres (K, 3), up in the camera's frame (3,), the true
    T_canonical_from_input (4, 4) in metres, the object's radius in metres) for up to
    ``per_class`` shapes of each class of the split, one view of each rule a shape."""
    classes = class_names(data)
    splits = load_splits(data, classes, 0.1, 0, cache)
    shapes = splits[{"val": "val", "test": "test"}[split]]
    rng = np.random.default_rng(seed)
    out = []
    for label, name in enumerate(classes):
        for i in np.flatnonzero(shapes.labels == label)[:per_class]:
            for rule in RULES:
                radius = float(rng.uniform(*real_radius_m(name)))
                config = replace(named_views(rule, name), radius_m=(radius, radius))
                # in its category's canonical frame, as its pose model reads it
                turned = shapes.shapes[i].points @ yaw_rotation(category(name).quarter_turns).T
                cloud, canonical_from_camera = scan_shape(turned, rng, config)
                up = invert_rigid(canonical_from_camera)[:3, :3] @ [0.0, 1.0, 0.0]
                tilt = rng.normal(size=3)
                tilt -= (tilt @ up) * up
                tilt *= np.tan(np.radians(UP_ERROR_DEG)) / np.linalg.norm(tilt)
                truth = canonical_from_camera.copy()
                truth[:3, 3] *= radius
                up = (up + tilt) / np.linalg.norm(up + tilt)
                out.append((rule, name, cloud * radius, up, truth, radius))
    return out


def named_right(views: list[View], model_dir: Path | None, pose: bool) -> NDArray[np.float64]:
    """(V,) 1.0 where the crop, its floor and walls taken away, is named its class; with
    ``pose``, where its class's model (the default request, up and the unit given) poses it
    within 10 degrees (its category's symmetric turns alike) and 0.1 of its radius."""
    from itnet.scene.posing import scene_catalog

    catalog = scene_catalog(model_dir)
    assert catalog.classifier is not None
    right = []
    for _, name, cloud, up, truth, radius in views:
        if pose:
            request = PoseRequest(units="m", up=up.tolist(), model=name)
            estimate = catalog.start(cloud, request).run_to_end().pose
            symmetry = category(name).symmetry
            turn = symmetric_rotation_error_deg(estimate[:3, :3], truth[:3, :3], symmetry)
            _, shift = pose_errors(estimate, truth, radius)
            right.append(float(is_correct(turn, shift)))
            continue
        request = PoseRequest(units="m", up=up.tolist())
        kept, _ = cut_out(cloud, request, Limits())
        answer = classify(catalog.classifier, kept, units="m", up=up)
        right.append(float(answer.category == name))
    return np.array(right)


def either_end() -> Any:
    """The floor's test with ``both_ends`` off: it goes where it runs on past at either end."""
    reaches = floor_and_walls._reaches_past

    def patched(plane: NDArray, rest: NDArray, axis: NDArray, tol: float, both_ends: bool) -> bool:
        return reaches(plane, rest, axis, tol, False)

    return patched


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=["val", "test"], default="val")
    parser.add_argument("--per-class", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--models-a", type=Path, default=None, help="default: shipped")
    parser.add_argument("--models-b", type=Path, default=None)
    parser.add_argument("--compare", choices=["floor-either-end"], default=None)
    parser.add_argument("--pose", action="store_true", help="posed right, not named right")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    views = crops(args.split, args.per_class, args.seed, args.data, args.cache)
    a = named_right(views, args.models_a, args.pose)
    if args.compare == "floor-either-end":
        served = floor_and_walls._reaches_past
        floor_and_walls._reaches_past = either_end()
        try:
            b = named_right(views, args.models_a, args.pose)
        finally:
            floor_and_walls._reaches_past = served
    else:
        b = named_right(views, args.models_b, args.pose)
    rows: dict[str, Any] = {}
    groups = {rule: [v[0] == rule for v in views] for rule in RULES}
    groups |= {name: [v[1] == name for v in views] for name in sorted({v[1] for v in views})}
    groups["all"] = [True] * len(views)
    print(f"{'views':28s} {'n':>5s} {'a':>7s} {'b':>7s} {'gain':>14s}")
    for key, mask in groups.items():
        m = np.asarray(mask)
        rows[key] = {"a": float(a[m].mean()), **paired_accuracy(b[m], a[m])}
        print(f"{key:28s} {m.sum():5d} {100 * a[m].mean():6.1f}% {100 * b[m].mean():6.1f}% "
              f"{rows[key]['gain']:+6.1f} ± {rows[key]['gain_stderr']:.1f}")  # fmt: skip
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
