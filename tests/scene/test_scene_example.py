"""The shipped example scene (itnet/examples/scene.png, made by scripts/make_scene_example.py)
through the CLI as the README runs it: every object it holds is found, named and posed right."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image
from typer.testing import CliRunner

from itnet.cli import app
from itnet.geometry import invert_rigid
from itnet.metrics import is_correct
from itnet.model.categories import MODELNET10
from itnet.symmetry import symmetric_rotation_error_deg

EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"


def test_the_example_scene_s_objects_are_found_named_and_posed() -> None:
    truth = json.loads((EXAMPLES / "scene_truth.json").read_text())
    camera = json.loads((EXAMPLES / "scene_camera.json").read_text())
    with Image.open(EXAMPLES / "scene.png") as image:
        assert image.mode.startswith("I;16") and image.size == (camera["width"], camera["height"])
    # a generous budget: every object gets its card's runs on a slow machine too
    result = CliRunner().invoke(app, [
        "scene", str(EXAMPLES / "scene.png"), "--intrinsics", str(EXAMPLES / "scene_camera.json"),
        "--budget-ms", "2000", "--json",
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    reply = json.loads(result.output.strip().splitlines()[-1])
    objects = reply["objects"]
    assert len(objects) == len(truth["objects"]) == 3
    depth = np.asarray(Image.open(EXAMPLES / "scene.png"), dtype=np.float64) / 1000

    def middle(obj: dict) -> np.ndarray:
        """The mean of a returned object's points (3,), camera frame."""
        v, u = np.divmod(np.asarray(obj["indices"]), camera["width"])
        z = depth[v, u]
        x, y = (u - camera["cx"]) * z / camera["fx"], (v - camera["cy"]) * z / camera["fy"]
        return np.stack([x, y, z], 1).mean(0)

    for known in truth["objects"]:
        pose = np.asarray(known["T_canonical_from_input"])
        centre = invert_rigid(pose)[:3, 3]
        # the returned object whose points' mean lies nearest the true centre
        obj = min(objects, key=lambda o: float(np.linalg.norm(middle(o) - centre)))
        assert obj["category"] == known["category"]
        estimate = np.asarray(obj["T_canonical_from_input"])
        rotation = float(symmetric_rotation_error_deg(
            estimate[:3, :3], pose[:3, :3], MODELNET10[known["category"]].symmetry
        ))  # fmt: skip
        error = float(np.linalg.norm(invert_rigid(estimate)[:3, 3] - centre)) / known["radius_m"]
        assert is_correct(rotation, error), (known["category"], rotation, error)
