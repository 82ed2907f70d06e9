"""Scenes benchmark: objects right, found and false, and the time per scene, on development
scenes (``model/scenes.py``: ModelNet10 test objects on a floor before a wall).

    python -m benchmarks.bench_scene --split validation --scenes 150
    python -m benchmarks.bench_scene --split test --scenes 150 --out runs/scenes-test.json

Each scene is rendered at 320x240 (and, unless ``--no-large``, another scene of the same kind at
640x480), written as a 16-bit PNG (millimetres) and found by ``itnet.scene.find_objects`` as a
user's file would be (the PNG read back, the intrinsics given); the time is the call's, PNG
decoding included. Scoring:

* a returned object matches the scene's object whose pixels it overlaps most, where their
  intersection over union is at least 0.5 (each scene object matched once, best first);
* found: scene objects matched; false: returned objects named by a category and matched to none
  (wall pieces, floor fragments, halves of objects, two objects as one) or matched to a thing of
  no category (``--distractors``: an ottoman named a bathtub; ``distractors_named`` of those
  found); such objects answered as unknown are counted apart (``unknown_unmatched``), as are
  scene objects found but answered as unknown (``unknown_objects``);
* right: matched, the category right, and the pose within (10 degrees, 0.1 radius) of the truth
  with the category's symmetry (SPEC.md); counted over the scene objects that are visible
  (at least ``--min-pixels`` pixels at 320x240, four times as many at 640x480).

With ``--room-views N`` each scene is a room's fused cloud instead (``make_room``: N cameras'
views fused, thinned to 1 cm, in a z-up frame whose origin lies on the floor), sent as a cloud
with up, the view or room decided by ``find_objects`` itself; objects' points for pixels.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from itnet.geometry import invert_rigid
from itnet.metrics import is_correct
from itnet.model.categories import MODELNET10
from itnet.model.scenes import (
    DEVELOPMENT,
    WITH_DESKS,
    Scene,
    SceneObjectTruth,
    add_kind_arguments,
    make_room,
    make_scene,
    matched_objects,
    scene_kind,
    split_shapes,
)
from itnet.scene import SceneFinishing, SceneResult, find_objects, scene_catalog
from itnet.scene.centre_along_floor import load_table
from itnet.scene.depth_io import depth_to_png
from itnet.scene.inputs import from_png
from itnet.scene.scene_classifier import load_scene_classifier
from itnet.scene.segment import SegmentOptions
from itnet.scene.warm_up import warm_up
from itnet.symmetry import symmetric_rotation_error_deg

ROOM_UP = (0.0, 0.0, 1.0)  # make_room's frame


def match(result: SceneResult, scene: Scene, min_pixels: int) -> list[dict]:
    """One row per scene object (``object``: its index in the scene, from 1) and per unmatched
    returned object: matched, right, errors."""
    count = len(scene.objects)
    sizes = np.bincount(scene.labels.ravel(), minlength=count + len(scene.others) + 1)
    pairs = matched_objects(
        [o.indices for o in result.objects], scene.labels, count + len(scene.others)
    )
    taken_obj, taken_truth, rows = set(), set(), []
    for i, k in pairs:
        if k > count:  # a thing of no category: false where named as one
            taken_obj.add(i)
            rows.append({"kind": "distractor", "other": scene.others[k - count - 1],
                         "predicted": result.objects[i].category,
                         "probability": result.objects[i].probability,
                         "unknown": result.objects[i].unknown})  # fmt: skip
            continue
        taken_obj.add(i)
        taken_truth.add(k)
        truth, obj = scene.objects[k - 1], result.objects[i]
        row = {"kind": "object", "object": k, "category": truth.category, "found": True,
               "predicted": obj.category, "probability": obj.probability,
               "unknown": obj.unknown, "visible": bool(sizes[k] >= min_pixels)}  # fmt: skip
        if obj.pose is not None and obj.category == truth.category:
            symmetry = MODELNET10[truth.category].symmetry
            rot = float(
                symmetric_rotation_error_deg(obj.pose[:3, :3], truth.pose[:3, :3], symmetry)
            )
            row.update(rotation_deg=rot, **centre_errors(obj.pose, truth))
            row["right"] = bool(is_correct(rot, row["centre_r"]))
        else:
            row["right"] = False
        rows.append(row)
    for k in range(1, len(scene.objects) + 1):
        if k not in taken_truth:
            rows.append({"kind": "object", "object": k, "category": scene.objects[k - 1].category,
                         "found": False, "right": False, "visible": bool(sizes[k] >= min_pixels)})  # fmt: skip
    rows += [{"kind": "false" if result.objects[i].category is not None else "unknown",
              "predicted": result.objects[i].category,
              "probability": result.objects[i].probability, "unknown": result.objects[i].unknown}
             for i in range(len(result.objects)) if i not in taken_obj]  # fmt: skip
    return rows


def centre_errors(pose: np.ndarray, truth: SceneObjectTruth) -> dict[str, float]:
    """An estimated pose T_canonical_from_input (4, 4) against the truth's -> the centre's error
    in radii: its length (``centre_r``), along the truth's canonical axes (``centre_x``, ``_y``,
    ``_z``: right, up, back), and along the camera's horizontal ray to the object
    (``centre_far``: positive beyond the truth, negative nearer the camera)."""
    truth_centre = invert_rigid(truth.pose)[:3, 3]
    error = (invert_rigid(pose)[:3, 3] - truth_centre) / truth.radius
    x, y, z = truth.pose[:3, :3] @ error
    up = invert_rigid(truth.pose)[:3, 1]  # the truth's canonical up in the camera frame
    ray = truth_centre - up * float(truth_centre @ up)  # from the camera, along the floor
    return {"centre_r": float(np.linalg.norm(error)), "centre_x": float(x), "centre_y": float(y),
            "centre_z": float(z), "centre_far": float(error @ ray / np.linalg.norm(ray))}  # fmt: skip


def false_answers(rows: list[dict]) -> int:
    """Named answers that match no object, and things of no category named."""
    return sum(r["kind"] == "false" or (r["kind"] == "distractor" and r["predicted"] is not None)
               for r in rows)  # fmt: skip


def summary(rows: list[dict], returned: int) -> dict:
    """Percentages with binomial standard errors."""
    objects = [r for r in rows if r["kind"] == "object" and r["visible"]]
    distractors = [r for r in rows if r["kind"] == "distractor"]
    named_distractors = sum(r["predicted"] is not None for r in distractors)
    false = false_answers(rows)
    unknown = sum(r["kind"] == "unknown" for r in rows)
    unknown_found = sum(r["found"] and r.get("predicted") is None for r in objects)

    def pct(k: int, n: int) -> dict:
        p = k / max(n, 1)
        return {"percent": round(100 * p, 1), "stderr": round(100 * (p * (1 - p) / max(n, 1)) ** 0.5, 1),
                "count": k, "of": n}  # fmt: skip

    by_category = {}
    for name in sorted({r["category"] for r in objects}):
        mine = [r for r in objects if r["category"] == name]
        by_category[name] = pct(sum(r["right"] for r in mine), len(mine))
    return {
        "right": pct(sum(r["right"] for r in objects), len(objects)),
        "found": pct(sum(r["found"] for r in objects), len(objects)),
        "category_right": pct(
            sum(r.get("predicted") == r["category"] for r in objects), len(objects)
        ),
        "false": pct(false, returned),
        # answered as unknown, matched to no object (a piece of one, a wall's strip)
        "unknown_unmatched": pct(unknown, returned),
        "unknown_objects": pct(unknown_found, len(objects)),
        # things of no category found (matched): named as a category (counted false above)
        "distractors_named": pct(named_distractors, len(distractors)),
        "by_category": by_category,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", choices=("validation", "test"), required=True)
    parser.add_argument("--scenes", type=int, default=150)
    parser.add_argument("--seed", type=int, default=None, help="default: 1 validation, 2 test")
    parser.add_argument("--budget-ms", type=float, default=None, help="default: find_objects'")
    parser.add_argument("--min-pixels", type=int, default=150)
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache/scenes"))
    parser.add_argument("--no-large", action="store_true", help="skip the 640x480 frames")
    parser.add_argument("--no-floor-centre", action="store_true", help="the network's centres")
    parser.add_argument(
        "--no-along-floor", action="store_true", help="no scene correction along the floor"
    )
    parser.add_argument(
        "--categories",
        default=None,
        help="'posed': the scenes' categories only (default: any)",
    )
    parser.add_argument(
        "--model-dir", type=Path, default=None, help="the models to serve (default: the shipped)"
    )
    parser.add_argument(
        "--no-recheck", action="store_true", help="no category recheck by the verifiers"
    )
    parser.add_argument(
        "--view-edge-deg",
        type=float,
        default=SceneFinishing.view_edge_deg,
        help="objects whose base is out of view (this near its bottom edge) are not rechecked "
        "(negative: all are)",
    )
    parser.add_argument(
        "--no-base-hidden-models",
        action="store_true",
        help="pose objects whose base is out of view by their category's own model",
    )
    parser.add_argument(
        "--no-scene-classifier",
        action="store_true",
        help="name the objects by the classifier and their height alone",
    )
    parser.add_argument(
        "--scene-classifier", type=Path, default=None, help="a scene classifier's file to name by"
    )
    parser.add_argument(
        "--centre-table", type=Path, default=None, help="a table of scene corrections to use"
    )
    parser.add_argument(
        "--no-split-touching", action="store_true", help="no cuts of clusters holding two objects"
    )
    parser.add_argument(
        "--with-desks", action="store_true", help="desks among the scenes' objects too"
    )
    parser.add_argument(
        "--touching", action="store_true", help="objects standing against each other (2-3)"
    )
    add_kind_arguments(parser, "the eight")
    parser.add_argument(
        "--room-views",
        type=int,
        default=0,
        help="rooms' fused clouds instead of depth images: each scene seen by this many cameras, "
        "fused, in a z-up frame of its own, sent with up (model.scenes.make_room)",
    )
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    seed = args.seed if args.seed is not None else {"validation": 1, "test": 2}[args.split]
    shapes = split_shapes(args.data, args.split, args.cache)
    budget: dict = {} if args.budget_ms is None else {"budget_ms": args.budget_ms}
    budget["finishing"] = SceneFinishing(
        not args.no_floor_centre,
        not args.no_along_floor,
        not args.no_recheck,
        args.view_edge_deg,
        base_hidden_models=not args.no_base_hidden_models,
    )
    budget["scene_classifier"] = not args.no_scene_classifier
    if args.scene_classifier is not None and not args.no_scene_classifier:
        namer = load_scene_classifier(args.scene_classifier)
        if namer is None:
            parser.error(f"--scene-classifier: no file {args.scene_classifier}")
        budget["scene_classifier"] = namer
    if args.centre_table is not None:
        if not args.centre_table.exists():
            parser.error(f"--centre-table: no file {args.centre_table}")
        budget["centre_table"] = load_table(args.centre_table)
    budget["options"] = SegmentOptions(split_touching=not args.no_split_touching)
    kind = scene_kind(args, parser, WITH_DESKS if args.with_desks else DEVELOPMENT)
    drawn, (low, high) = kind["categories"], kind["pitch_deg"]
    kind["touching"] = args.touching
    if args.categories == "posed":
        budget["categories"] = frozenset(drawn)
    if args.model_dir is not None:
        budget["catalog"] = scene_catalog(args.model_dir)
    warm_up(budget.get("catalog"))  # the models loaded, the scene path run once
    rng = np.random.default_rng(seed)
    rows: list[dict] = []
    returned, times, times_large, rows_large, returned_large = 0, [], [], [], 0
    for s in range(args.scenes):
        if args.room_views:
            points, scene = make_room(shapes, rng, args.room_views, **kind)
            start = time.perf_counter()
            result = find_objects(points, started=start, expected_up=ROOM_UP, **budget)
        else:
            scene = make_scene(shapes, rng, **kind)
            png = depth_to_png(np.round(scene.depth * 1000).astype(np.uint16))
            start = time.perf_counter()
            result = find_objects(from_png(png, scene.intrinsics), started=start, **budget)
        times.append((time.perf_counter() - start) * 1e3)
        rows += [{"scene": s, **row} for row in match(result, scene, args.min_pixels)]
        returned += len(result.objects)
        if not args.no_large and not args.room_views:
            big = large_scene(shapes, seed, s, **kind)
            png = depth_to_png(np.round(big.depth * 1000).astype(np.uint16))
            start = time.perf_counter()
            result = find_objects(from_png(png, big.intrinsics), started=start, **budget)
            times_large.append((time.perf_counter() - start) * 1e3)
            rows_large += [{"scene": s, **row} for row in match(result, big, 4 * args.min_pixels)]
            returned_large += len(result.objects)
    report = {
        "split": args.split, "scenes": args.scenes, "seed": seed, "touching": args.touching,
        "with_desks": args.with_desks, "drawn": list(drawn), "pitch_deg": [low, high],
        "most": args.most, "cut_off": args.cut_off, "flying_pixels": args.flying_pixels,
        "distractors": args.distractors, "sensor": args.sensor, "room_views": args.room_views,
        "against_wall": args.against_wall, "on_top": args.on_top,
        **{k: sorted(v) if isinstance(v, frozenset) else v for k, v in budget.items()
           if k not in ("catalog", "finishing", "options", "scene_classifier", "centre_table")},
        **({"centre_table": str(args.centre_table)} if args.centre_table is not None else {}),
        "scene_classifier": (str(args.scene_classifier) if args.scene_classifier is not None
                             else True) if not args.no_scene_classifier else False,
        "split_touching": not args.no_split_touching,
        **asdict(budget["finishing"]),
        **({"model_dir": str(args.model_dir)} if args.model_dir is not None else {}),
        "320x240": summary(rows, returned) | timing(times),
        **({"640x480": summary(rows_large, returned_large) | timing(times_large)} if times_large else {}),
    }  # fmt: skip
    print(json.dumps(report, indent=1))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            json.dumps({**report, "rows": rows, "rows_640x480": rows_large}, indent=1)
        )


def large_scene(shapes: dict, seed: int, index: int, **kind: Any) -> Scene:
    """A scene of the same ``kind`` (``make_scene``'s keywords) at 640x480, drawn from its own
    generator (seed, index)."""
    rng = np.random.default_rng([seed, index, 640])
    return make_scene(shapes, rng, 640, 480, **kind)


def timing(ms: list[float]) -> dict:
    return {
        "ms_median": round(float(np.median(ms)), 1),
        "ms_p95": round(float(np.percentile(ms, 95)), 1),
    }


if __name__ == "__main__":
    main()
