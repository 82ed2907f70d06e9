"""What a scene costs at each camera resolution: the segmentation's time, the reply's time
against the budget, and how many of the objects found are posed.

    python -m benchmarks.bench_scene_cost --scenes 30 --json docs/scene_cost.json

The same development scenes (``model/scenes.py``, validation shapes, up to ``--most`` objects
each) are rendered at every resolution, with the camera's field of view kept, written as 16-bit
PNGs and found by ``itnet.scene.find_objects`` as a user's files are, the clock started before
the PNG is decoded. With ``--real``, the real frames of ``../shared/data/real`` are added,
resampled to each resolution (nearest pixel, the intrinsics scaled with them).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from itnet.model.scenes import DEVELOPMENT, make_scene, split_shapes
from itnet.scene import find_objects, scene_catalog
from itnet.scene.camera import Intrinsics, parse_intrinsics
from itnet.scene.depth_io import depth_to_png, png_to_depth
from itnet.scene.inputs import from_png
from itnet.scene.pipeline import DEFAULT_BUDGET_MS
from itnet.scene.warm_up import warm_up

RESOLUTIONS = ((320, 240), (640, 480), (960, 540), (1280, 720))


def resampled(depth: np.ndarray, camera: Intrinsics, width: int, height: int):
    """A depth image (H, W) and its intrinsics at another resolution (nearest pixel)."""
    rows = (np.arange(height) * depth.shape[0] / height).astype(int)
    cols = (np.arange(width) * depth.shape[1] / width).astype(int)
    sx, sy = width / depth.shape[1], height / depth.shape[0]
    return depth[rows][:, cols], Intrinsics(camera.fx * sx, camera.fy * sy, camera.cx * sx,
                                            camera.cy * sy)  # fmt: skip


def measure(frames: list[tuple[bytes, Intrinsics]], budget: float, catalog: Any) -> dict:
    """Every frame (PNG bytes, intrinsics) found once -> the times and the objects posed."""
    segment, reply, found, posed, late = [], [], 0, 0, 0
    for png, camera in frames:
        started = time.perf_counter()
        result = find_objects(from_png(png, camera), budget_ms=budget, catalog=catalog,
                              started=started)  # fmt: skip
        took = (time.perf_counter() - started) * 1e3
        segment.append(result.segment_ms)
        reply.append(took)
        late += took > budget + 5.0
        found += len(result.objects)
        posed += sum(o.pose is not None or o.no_pose in ("unknown", "no_pose_model")
                     for o in result.objects)  # fmt: skip
    return {
        "frames": len(frames),
        "segment_ms_median": round(statistics.median(segment), 1),
        "segment_ms_p95": round(float(np.percentile(segment, 95)), 1),
        "reply_ms_median": round(statistics.median(reply), 1),
        "reply_ms_p95": round(float(np.percentile(reply, 95)), 1),
        "reply_ms_max": round(max(reply), 1),
        "late_over_5ms": late,
        "objects": found,
        "posed_or_answered": posed,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument("--most", type=int, default=4, help="objects a scene holds at most")
    parser.add_argument("--budget-ms", type=float, default=DEFAULT_BUDGET_MS)
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache/scenes"))
    parser.add_argument("--real", type=Path, default=None, help="also the real frames here")
    parser.add_argument(
        "--resolutions",
        default=",".join(f"{w}x{h}" for w, h in RESOLUTIONS),
        help="WxH,... (default: all four)",
    )
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    sizes = [tuple(int(v) for v in size.split("x")) for size in args.resolutions.split(",")]
    catalog = scene_catalog()
    warm_up(catalog)
    shapes = split_shapes(args.data, "validation", args.cache)
    report: dict[str, Any] = {
        "budget_ms": args.budget_ms, "scenes": args.scenes,
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine()},
    }  # fmt: skip
    for width, height in sizes:
        rng = np.random.default_rng(5)
        frames = []
        for _ in range(args.scenes):
            scene = make_scene(shapes, rng, width, height, categories=DEVELOPMENT, most=args.most)
            frames.append((depth_to_png(np.round(scene.depth * 1000).astype(np.uint16)),
                           scene.intrinsics))  # fmt: skip
        row = {"development": measure(frames, args.budget_ms, catalog)}
        if args.real is not None:
            real = []
            for frame in json.loads((args.real / "boxes.json").read_text())["frames"]:
                depth = png_to_depth((args.real / frame["depth"]).read_bytes())
                camera = parse_intrinsics(str(args.real / frame["intrinsics"]))
                small, k = resampled(depth, camera, width, height)
                real += [(depth_to_png(small), k)] * 5
            row["real"] = measure(real, args.budget_ms, catalog)
        report[f"{width}x{height}"] = row
        print(f"{width}x{height}: {json.dumps(row)}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
