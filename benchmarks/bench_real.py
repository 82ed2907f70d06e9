"""Real depth frames: what the scene pipeline finds, names and poses in frames a real camera
took, against their annotated 3-D boxes (``../shared/data/real``: SUN RGB-D Kinect v2 frames;
its README says what each file holds).

    python -m benchmarks.bench_real --json docs/real_frames.json

Each frame is found by ``itnet.scene.find_objects`` as a user's file would be (the PNG read,
the intrinsics given), at the default budget unless ``--budget-ms``; the first call of each
frame warms up and is not counted. Scoring, per annotated box (grown by ``--grow`` on each side):

* a returned object belongs to the box that holds most of its points, where that is at least
  half of them; a box is found where its largest such object holds at least a fifth of the
  frame's points inside the box (a foot-board alone is not a bed found);
* named: found, and the object's category is the box's (ours; boxes of other kinds, a lamp, an
  ottoman, a mirror, are right when answered unknown or not at all, and false when named);
* turn: the angle about up between the object's canonical front (+z) and the box's, modulo the
  category's turns (180 degrees for a night stand or dresser, whose two long sides are alike
  to a depth camera), for objects found with a pose;
* crops: each box of our categories cut out of the frame (grown by ``--grow``: a strip of the
  floor and of what stands beside it comes along, as from a user's own box) and named by
  ``itnet.pose.recognition.classify`` in metres with the frame's up, as ``itnet classify
  crop.ply --units m --up x,y,z`` names it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from itnet.scene import find_objects, scene_catalog
from itnet.scene.camera import parse_intrinsics
from itnet.scene.inputs import SceneInput, from_file

DATA = Path("../shared/data/real")
# the turn about up that leaves a category's box alike: 180 degrees for boxes whose front and
# back a depth camera cannot tell apart from the box alone
TURN_MODULO_DEG = {"night_stand": 180.0, "dresser": 180.0}


def inside(points: NDArray, box: dict[str, Any], grow: float) -> NDArray[np.bool_]:
    """Which points (N, 3) lie inside an annotated box grown by ``grow`` metres a side."""
    rotation = np.asarray(box["R_input_from_box"], dtype=np.float64)
    local = (points - np.asarray(box["centre"])) @ rotation
    half = np.asarray(box["size"]) / 2 + grow
    return np.all(np.abs(local) <= half, axis=1)


def turn_error_deg(pose: NDArray, box: dict[str, Any], up: NDArray, modulo: float) -> float:
    """The angle about ``up`` (3,) between a pose's canonical +z (T_canonical_from_input (4, 4))
    and the box's third axis, modulo ``modulo`` degrees, in [0, modulo / 2]."""

    def heading(axis: NDArray) -> NDArray:
        flat = axis - (axis @ up) * up
        return flat / max(float(np.linalg.norm(flat)), 1e-12)

    ours = heading(np.asarray(pose)[:3, :3].T[:, 2])
    theirs = heading(np.asarray(box["R_input_from_box"])[:, 2])
    angle = math.degrees(math.atan2(float(np.cross(theirs, ours) @ up), float(theirs @ ours)))
    angle %= modulo
    return min(angle, modulo - angle)


def score_frame(frame: dict[str, Any], result: Any, given: SceneInput, grow: float) -> list[dict]:
    """A frame's annotation, its SceneResult and its SceneInput (the points the result's
    indices name) -> a row per box and per returned object no box holds."""
    points = given.points
    up = np.asarray(frame["up"], dtype=np.float64)
    up /= np.linalg.norm(up)
    masks = [inside(points, box, grow) for box in frame["objects"]]
    owner: dict[int, list[tuple[int, int]]] = {}
    rows: list[dict] = []
    for k, obj in enumerate(result.objects):
        rows_of = np.searchsorted(given.indices, obj.indices)
        shares = [int(m[rows_of].sum()) for m in masks]
        best = int(np.argmax(shares)) if shares else -1
        if best < 0 or shares[best] < len(obj.indices) / 2:
            rows.append({"kind": "unmatched", "category": obj.category,
                         "points": len(obj.indices)})  # fmt: skip
            continue
        owner.setdefault(best, []).append((shares[best], k))
    for b, box in enumerate(frame["objects"]):
        row: dict[str, Any] = {"kind": "box", "class": box["class"], "category": box["category"]}
        candidates = sorted(owner.get(b, []), reverse=True)
        found = bool(candidates) and bool(candidates[0][0] >= 0.2 * masks[b].sum())
        row["found"] = found
        if candidates:
            obj = result.objects[candidates[0][1]]
            row |= {"answered": obj.category, "probability": obj.probability,
                    "share": round(candidates[0][0] / max(int(masks[b].sum()), 1), 3)}  # fmt: skip
            if found and obj.pose is not None and box["category"] is not None:
                modulo = TURN_MODULO_DEG.get(box["category"], 360.0)
                row["turn_deg"] = round(turn_error_deg(obj.pose, box, up, modulo), 1)
        row["named"] = found and row.get("answered") == box["category"]
        if box["category"] is None:  # none of ours: right unless named as one of ours
            row["false"] = [result.objects[k].category for _, k in candidates
                            if result.objects[k].category is not None]  # fmt: skip
        rows.append(row)
    return rows


def crop_rows(
    frame: dict[str, Any], given: SceneInput, grow: float, classifier: Any, strip: bool | None
) -> list[dict]:
    """A row per box of our categories: its crop's answer (category, probability, unsure), the
    crop's floor and walls taken away unless ``strip`` is false, as ``itnet classify`` does."""
    from itnet.pose.cloud import Limits, cut_out
    from itnet.pose.recognition import classify
    from itnet.pose.request import PoseRequest

    rows = []
    request = PoseRequest(units="m", up=frame["up"], strip=strip)
    for box in frame["objects"]:
        if box["category"] is None:
            continue
        crop = given.points[inside(given.points, box, grow)]
        kept, stripped = cut_out(crop, request, Limits())
        answer = classify(classifier, kept, units="m", up=frame["up"])
        rows.append({
            "category": box["category"], "points": len(crop), "answered": answer.category,
            "probability": round(answer.probability, 3), "unsure": answer.unsure,
            "named": answer.category == box["category"],
            "stripped": None if stripped is None else stripped.as_dict(),
        })  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--budget-ms", type=float, default=None, help="default: find_objects'")
    parser.add_argument("--grow", type=float, default=0.1, help="metres a box grows a side")
    parser.add_argument("--no-strip", dest="strip", action="store_const", const=False,
                        default=None, help="crops keep their floor and walls")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per frame")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    frames = json.loads((args.data / "boxes.json").read_text())["frames"]
    catalog = scene_catalog()
    budget = {} if args.budget_ms is None else {"budget_ms": args.budget_ms}
    out: dict[str, Any] = {"frames": [], "machine": {"cpus": os.cpu_count(),
                                                       "processor": platform.processor()}}  # fmt: skip
    for frame in frames:
        path = args.data / frame["depth"]
        camera = parse_intrinsics(str(args.data / frame["intrinsics"]))
        given = from_file(path, camera)
        find_objects(path, camera, catalog=catalog, **budget)  # warm-up
        times, result = [], None
        for _ in range(args.repeats):
            started = time.perf_counter()
            result = find_objects(path, camera, catalog=catalog, started=started, **budget)
            times.append((time.perf_counter() - started) * 1e3)
        assert result is not None
        rows = score_frame(frame, result, given, args.grow)
        out["frames"].append({
            "frame": frame["frame"], "budget_ms": result.budget_ms,
            "ms_median": round(statistics.median(times), 1), "ms_max": round(max(times), 1),
            "segment_ms": round(result.segment_ms, 1),
            "posed": sum(o.pose is not None for o in result.objects),
            "objects": len(result.objects), "rows": rows,
            "crops": crop_rows(frame, given, args.grow, catalog.classifier, args.strip),
        })  # fmt: skip
        print(f"{frame['frame']}: {len(result.objects)} objects, {statistics.median(times):.0f} ms "
              f"median ({max(times):.0f} max) of {result.budget_ms:g}, segmentation "
              f"{result.segment_ms:.0f} ms")  # fmt: skip
        for row in rows:
            print("   ", json.dumps(row))
        for row in out["frames"][-1]["crops"]:
            print("    crop", json.dumps(row))
    boxes = [r for f in out["frames"] for r in f["rows"] if r["kind"] == "box"]
    ours = [r for r in boxes if r["category"] is not None]
    out["summary"] = {
        "ours": len(ours), "found": sum(r["found"] for r in ours),
        "named": sum(r["named"] for r in ours),
        "turn_within_20": sum(r.get("turn_deg", 999) <= 20 for r in ours),
        "others": len(boxes) - len(ours),
        "others_named_false": sum(bool(r.get("false")) for r in boxes if r["category"] is None),
        "crops": sum(len(f["crops"]) for f in out["frames"]),
        "crops_named": sum(r["named"] for f in out["frames"] for r in f["crops"]),
    }  # fmt: skip
    print(json.dumps(out["summary"]))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
