"""How fast recordings are read and answered: a 640x480, 30 frames/s depth recording (the example
scene at twice its size, a CameraInfo a frame) of ``--frames`` frames in each kind of bag, read
to depth arrays and intrinsics (reading alone), then ``--answer`` of its frames answered by the
scene pipeline at the default budget.

    python -m benchmarks.bench_recording --frames 300 --answer 60 --json docs/recordings.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.recording import KINDS, write_recording
from itnet.scene.camera import Intrinsics, parse_intrinsics
from itnet.scene.depth_io import png_to_depth

EXAMPLES = Path(__file__).resolve().parents[1] / "itnet" / "examples"


def vga_frame() -> tuple[np.ndarray, Intrinsics]:
    """The example scene at 640x480: each pixel doubled, the focal length with it."""
    depth = png_to_depth((EXAMPLES / "scene.png").read_bytes())
    camera = parse_intrinsics(str(EXAMPLES / "scene_camera.json"))
    big = np.repeat(np.repeat(depth, 2, axis=0), 2, axis=1)
    return big, Intrinsics(camera.fx * 2, camera.fy * 2, camera.cx * 2 + 0.5, camera.cy * 2 + 0.5)


def read_rate(path: Path) -> dict:
    """Every frame read to its depth array and intrinsics: frames/s, three tries, the best."""
    from itnet.recordings import Selection, open_recording

    best = 0.0
    frames = 0
    for _ in range(3):
        started = time.perf_counter()
        with open_recording(path) as recording:
            frames = sum(1 for f in recording.frames(Selection()) if f.depth is not None)  # type: ignore[union-attr]
        best = max(best, frames / (time.perf_counter() - started))
    return {"frames": frames, "frames_per_s": round(best, 1)}


def answer_rate(path: Path, count: int, budget_ms: float) -> dict:
    """The first ``count`` frames answered in turn: frames/s, each reply's time, objects posed."""
    from itnet.recordings import Selection, scene_answers
    from itnet.recordings.answer import SceneAnswer, scene_finder
    from itnet.scene import scene_catalog
    from itnet.scene.warm_up import warm_up

    catalog = scene_catalog()
    warm_up(catalog)
    find = scene_finder(catalog, {"budget_ms": budget_ms})

    period_s = 1 / 30
    started = time.perf_counter()
    elapsed, objects, posed = [], 0, 0
    for item in scene_answers(path, Selection(end_s=(count - 0.5) * period_s), find):
        assert isinstance(item, SceneAnswer), item
        elapsed.append(item.result.elapsed_ms)
        objects += len(item.result.objects)
        posed += sum(o.pose is not None for o in item.result.objects)
    seconds = time.perf_counter() - started
    return {
        "frames": len(elapsed),
        "frames_per_s": round(len(elapsed) / seconds, 2),
        "reply_ms_median": round(float(np.median(elapsed)), 1),
        "reply_ms_p95": round(float(np.percentile(elapsed, 95)), 1),
        "objects": objects,
        "posed": posed,
        "budget_ms": budget_ms,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--answer", type=int, default=60, help="frames answered (of the ROS 1 bag)")
    parser.add_argument("--budget-ms", type=float, default=None, help="default: the scene default")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    from itnet.scene import DEFAULT_BUDGET_MS

    depth, camera = vga_frame()
    report: dict = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "frame": f"{depth.shape[1]}x{depth.shape[0]} 16UC1 at 30 frames/s, a CameraInfo a frame",
        "read": {},
    }
    with tempfile.TemporaryDirectory() as folder:
        for kind in KINDS:
            path = Path(folder) / ("rec.bag" if kind == "ros1" else f"rec_{kind}")
            write_recording(path, kind, [depth] * args.frames, camera)
            report["read"][kind] = read_rate(path)
            print(f"{kind}: {report['read'][kind]}", flush=True)
        budget = args.budget_ms or DEFAULT_BUDGET_MS
        report["answer"] = answer_rate(Path(folder) / "rec.bag", args.answer, budget)
        print(f"answered: {report['answer']}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
