"""Make the example scene in itnet/examples/: a depth image of held-out objects on a floor.

    .venv/bin/python scripts/make_scene_example.py

One development scene (``itnet.model.scenes.make_scene``, as the scene benchmark makes them) of
ModelNet10 *test* shapes (the test half: never trained on, never used to choose a setting),
seen at 320x240 by a camera 1.1-1.7 m above the floor, the first scene of the seed with at least
``--objects`` objects. Writes:

* ``scene.png``: the depth image, 16-bit greyscale, millimetres (as a depth camera's driver
  writes it);
* ``scene_camera.json``: the camera's intrinsics (``fx``, ``fy``, ``cx``, ``cy``, pixels), as
  ``itnet scene --intrinsics`` reads them;
* ``scene_truth.json``: each object's category, shape, radius and true
  ``T_canonical_from_input`` (the camera frame, metres), and how many pixels it covers, for
  checking ``itnet scene``'s answer.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from itnet.model.scenes import make_scene, split_shapes
from itnet.scene.depth_io import depth_to_png

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=25)
    parser.add_argument("--objects", type=int, default=3, help="the least objects in the scene")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared/data/modelnet10")
    parser.add_argument("--cache", type=Path, default=ROOT / "cache/scenes")
    parser.add_argument("--out", type=Path, default=ROOT / "itnet/examples")
    args = parser.parse_args()

    shapes = split_shapes(args.data, "test", args.cache)
    rng = np.random.default_rng(args.seed)
    scene = make_scene(shapes, rng)
    while len(scene.objects) < args.objects:
        scene = make_scene(shapes, rng)
    args.out.mkdir(parents=True, exist_ok=True)
    millimetres = np.round(scene.depth * 1000).astype(np.uint16)
    (args.out / "scene.png").write_bytes(depth_to_png(millimetres))
    camera = {**{k: round(v, 4) for k, v in scene.intrinsics.as_dict().items()},
              "width": scene.depth.shape[1], "height": scene.depth.shape[0]}  # fmt: skip
    (args.out / "scene_camera.json").write_text(json.dumps(camera, indent=1) + "\n")
    pixels = np.bincount(scene.labels.ravel(), minlength=len(scene.objects) + 1)
    truth = {
        "source": f"scripts/make_scene_example.py --seed {args.seed}: ModelNet10 test shapes, "
        "a development scene of itnet.model.scenes",
        "depth_scale": 1000,
        "objects": [
            {"category": o.category, "shape": o.name, "radius_m": round(o.radius, 4),
             "pixels": int(pixels[k]), "T_canonical_from_input": np.round(o.pose, 6).tolist()}
            for k, o in enumerate(scene.objects, start=1)
        ],
    }  # fmt: skip
    (args.out / "scene_truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {args.out}/scene.png, scene_camera.json, scene_truth.json:",
          ", ".join(o.category for o in scene.objects))  # fmt: skip


if __name__ == "__main__":
    main()
