"""A scene object's centre moved along the floor by its pose model's scene correction: the math,
the table that ties a correction to one graph, its fit, and find_objects applying it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.centre import FEATURE_COUNTS, FEATURES, FEATURES_VIEWPOINT, CentreCorrection
from itnet.cli import app
from itnet.geometry import axis_angle_to_matrix, invert_rigid
from itnet.graph_digest import graph_digest
from itnet.model.scenes import Scene, matched_objects
from itnet.pose.runtime import default_model_dir
from itnet.scene import SceneFinishing, find_objects
from itnet.scene.centre_along_floor import (
    CentreTable,
    centred_along_floor,
    load_table,
    moved_object,
    true_offset,
)
from itnet.scene.pipeline import shipped_catalog

F = FEATURE_COUNTS[FEATURES_VIEWPOINT]
UP = np.array([0.0, -1.0, 0.0])  # a level camera's floor normal (y down in its frame)


def constant(offset: tuple[float, float, float], features: str = FEATURES_VIEWPOINT):
    """A correction that predicts ``offset`` (normalised units) whatever the features."""
    f = FEATURE_COUNTS[features]
    weights = np.zeros((f + 1, 3))
    weights[-1] = offset
    return CentreCorrection(np.zeros(f), np.ones(f), weights, features)


def object_at(centre: np.ndarray, yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (300, 3) of a box in the camera frame and its pose T_canonical_from_input."""
    rng = np.random.default_rng(3)
    local = rng.uniform(-1, 1, (300, 3)) * [0.3, 0.45, 0.25]
    rotation = axis_angle_to_matrix([0.0, 1.0, 0.0], np.radians(yaw_deg))  # canonical -> camera
    camera_from_canonical = np.eye(4)
    camera_from_canonical[:3, :3], camera_from_canonical[:3, 3] = rotation, centre
    points = local @ rotation.T + centre
    return points, invert_rigid(camera_from_canonical)


def centre_of(pose: np.ndarray) -> np.ndarray:
    return -pose[:3, :3].T @ pose[:3, 3]


def test_the_centre_moves_along_the_floor_only_by_the_predicted_offset() -> None:
    points, pose = object_at(np.array([0.4, 0.5, 3.0]), 35.0)
    offset = (0.2, 0.3, -0.1)  # in the moved, normalised frame
    moved = centred_along_floor(points, pose, constant(offset), np.zeros(3), UP)
    seen = moved_object(points, pose, np.zeros(3))
    expected = seen.normalization.scale * pose[:3, :3].T @ np.array(offset)  # in the camera frame
    expected -= (expected @ UP) * UP
    assert np.allclose(centre_of(moved) - centre_of(pose), expected, atol=1e-9)
    assert abs((centre_of(moved) - centre_of(pose)) @ UP) < 1e-9  # the height is the floor's
    assert np.allclose(moved[:3, :3], pose[:3, :3])  # the rotation is the pose's
    assert np.allclose(centred_along_floor(points, pose, constant((0, 0, 0)), np.zeros(3), UP),
                       pose)  # fmt: skip
    with pytest.raises(ValueError, match="viewpoint"):  # the camera on the estimated centre
        centred_along_floor(points, pose, constant(offset), centre_of(pose), UP)


def test_the_true_offset_is_where_the_truth_lies_in_the_moved_frame() -> None:
    points, truth = object_at(np.array([-0.3, 0.6, 2.5]), -60.0)
    seen = moved_object(points, truth, np.zeros(3))
    assert np.allclose(true_offset(seen, truth), 0.0, atol=1e-9)  # the estimate is the truth
    shifted = truth.copy()
    shifted[:3, 3] += [0.1, 0.0, -0.05]  # the estimated centre 0.1, 0.05 m off (canonical axes)
    seen = moved_object(points, shifted, np.zeros(3))
    assert np.allclose(true_offset(seen, truth) * seen.normalization.scale, [0.1, 0.0, -0.05])
    assert seen.features.shape == (F,)


def test_the_table_holds_a_correction_for_one_graph(tmp_path: Path) -> None:
    graph = tmp_path / "chair.onnx"
    graph.write_bytes((default_model_dir() / "chair.onnx").read_bytes())
    table = CentreTable({"chair": (graph_digest(graph), constant((0.1, 0, 0)))})
    again = CentreTable.from_dict(json.loads(json.dumps(table.to_dict())))
    found = again.for_model("chair", graph)
    assert found is not None and np.allclose(found.weights[-1], [0.1, 0, 0])
    assert again.for_model("table", graph) is None  # none fitted for that model
    other = tmp_path / "other.onnx"
    other.write_bytes((default_model_dir() / "table.onnx").read_bytes())
    assert again.for_model("chair", other) is None  # fitted for another graph of that name
    plain = {"chair": {"graph_sha256": "0", "correction": constant((0, 0, 0), FEATURES).to_dict()}}
    with pytest.raises(ValueError, match="camera's direction"):
        CentreTable.from_dict(plain)
    assert load_table(tmp_path / "missing.json").corrections == {}


def test_returned_objects_are_matched_once_each_by_overlap() -> None:
    labels = np.zeros((4, 6), np.int64)
    labels[:, :3], labels[:, 3:] = 1, 2
    flat = np.arange(24).reshape(4, 6)
    returned = [flat[:, 3:].ravel(), flat[:, :2].ravel(), flat[:, 4:].ravel(), flat[0].ravel()]
    # the first covers object 2 whole; the second 8 of object 1's 12 pixels (IoU 0.67); the
    # third is a smaller part of object 2 (taken); the fourth a row across both
    assert matched_objects(returned, labels, 2) == [(0, 2), (1, 1)]


def _fit(arguments: list[str]) -> None:
    """``itnet fit scene-centre ARGUMENTS`` as a user runs it."""
    result = CliRunner().invoke(app, ["fit", "scene-centre", *arguments])
    assert result.exit_code == 0, result.output


def test_the_fit_writes_a_table_for_the_models_it_has_enough_objects_of(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(60, F))
    y = np.array([0.05, 0.0, 0.12]) + 0.01 * rng.normal(size=(60, 3))
    samples = tmp_path / "samples.npz"
    np.savez(samples, **{"chair/x": x, "chair/y": y, "bed/x": x[:5], "bed/y": y[:5]})
    out = tmp_path / "table.json"
    _fit(["--samples", str(samples), "--out", str(out)])
    table = CentreTable.from_dict(json.loads(out.read_text()))
    assert set(table.corrections) == {"chair"}  # the bed's 5 objects are too few
    chair = shipped_catalog().models["chair"]
    correction = table.for_model("chair", chair.path)
    assert correction is not None  # tied to the shipped chair's graph
    assert np.allclose(correction.predict(x).mean(0), [0.05, 0.0, 0.12], atol=0.01)


def test_a_fit_of_some_models_keeps_the_others_corrections(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(60, F))
    samples = tmp_path / "samples.npz"
    y = {"chair": [0.05, 0.0, 0.12], "toilet": [-0.1, 0.0, 0.0]}
    arrays = {f"{n}/{k}": v for n, o in y.items()
              for k, v in (("x", x), ("y", np.tile(o, (60, 1))))}  # fmt: skip
    np.savez(samples, **arrays)
    out = tmp_path / "table.json"
    _fit(["--samples", str(samples), "--out", str(out), "--only", "chair"])
    assert set(CentreTable.from_dict(json.loads(out.read_text())).corrections) == {"chair"}
    y["chair"] = [0.2, 0.0, 0.0]
    arrays = {f"{n}/{k}": v for n, o in y.items()
              for k, v in (("x", x), ("y", np.tile(o, (60, 1))))}  # fmt: skip
    np.savez(samples, **arrays)
    _fit(["--samples", str(samples), "--out", str(out), "--only", "toilet"])
    table = CentreTable.from_dict(json.loads(out.read_text()))
    assert set(table.corrections) == {"chair", "toilet"}
    chair = table.corrections["chair"][1]  # the first fit's, kept
    assert np.allclose(chair.predict(x).mean(0), [0.05, 0.0, 0.12], atol=0.01)
    assert np.allclose(table.corrections["toilet"][1].predict(x).mean(0), [-0.1, 0, 0], atol=0.01)


def test_find_objects_moves_each_posed_object_along_the_floor(chair_scene: Scene) -> None:
    plain = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=1000,
                         finishing=SceneFinishing(along_floor=False, recheck=False))  # fmt: skip
    (obj,) = plain.objects
    assert obj.pose is not None and obj.run is not None
    assert obj.run["centre_along_floor"] is False
    model = shipped_catalog().models[obj.run["model"]]
    table = CentreTable({model.card.name: (graph_digest(model.path), constant((0.0, 0.0, 0.5)))})
    moved = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=1000,
                         centre_table=table, finishing=SceneFinishing(recheck=False))  # fmt: skip
    (again,) = moved.objects
    assert again.run is not None and again.run["centre_along_floor"] is True
    assert np.allclose(again.pose[:3, :3], obj.pose[:3, :3], atol=1e-4)  # the same run
    move = centre_of(again.pose) - centre_of(obj.pose)
    up = np.asarray(plain.up)
    assert abs(move @ up) < 1e-6  # the floor keeps the height
    back = again.pose[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # canonical +z in the camera frame
    back -= (back @ up) * up
    assert move @ back > 0.9 * np.linalg.norm(move) > 0  # moved toward the object's back
