"""Objects standing against each other: the candidate cuts, the cut judge, its file and fit, and
the cut inside the segmentation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scene_helpers import FEATURES, boxes_shape, make_test_scene, sure_judge
from typer.testing import CliRunner

from itnet.cli import app
from itnet.model import touching_cut_fit
from itnet.model.scenes import Scene
from itnet.planes import Plane
from itnet.scene import segment as segment_module
from itnet.scene.feature_network import FeatureNetwork
from itnet.scene.inputs import from_depth
from itnet.scene.segment import SegmentOptions, segment
from itnet.scene.touching import (
    CutJudge,
    cut_candidates,
    load_cut_judge,
    split_touching,
)

FLOOR = Plane(np.array([0.0, -1.0, 0.0]), 1.5)  # camera frame: y down, the floor 1.5 m below


def box_surface(x: tuple[float, float], z: tuple[float, float], top: float) -> np.ndarray:
    """What a camera at the origin sees of a box on FLOOR: its front (z = z0) and its top, on
    a 1 cm grid (camera frame, metres)."""
    xs, heights, zs = (np.arange(*x, 0.01), np.arange(0.0, top, 0.01), np.arange(*z, 0.01))
    front = np.stack(np.meshgrid(xs, heights, indexing="ij"), -1).reshape(-1, 2)
    lid = np.stack(np.meshgrid(xs, zs, indexing="ij"), -1).reshape(-1, 2)
    return np.concatenate([
        np.stack([front[:, 0], 1.5 - front[:, 1], np.full(len(front), z[0])], 1),
        np.stack([lid[:, 0], np.full(len(lid), 1.5 - top), lid[:, 1]], 1),
    ])  # fmt: skip


@pytest.fixture(scope="module")
def two_boxes_cloud() -> tuple[np.ndarray, np.ndarray]:
    """Two boxes 3 cm apart along x, of different heights (points, which box (N,))."""
    a = box_surface((-0.6, -0.03), (3.0, 3.5), 0.8)
    b = box_surface((0.0, 0.5), (3.0, 3.4), 0.5)
    return np.concatenate([a, b]), np.repeat([0, 1], [len(a), len(b)])


def test_the_emptiest_cut_parts_two_boxes_at_their_gap(two_boxes_cloud: tuple) -> None:
    points, box = two_boxes_cloud
    cuts = cut_candidates(points, FLOOR)
    assert 1 <= len(cuts) <= 6
    side = cuts[0].side(points)
    assert np.array_equal(side, box == 0) or np.array_equal(side, box == 1)
    assert abs(cuts[0].normal @ FLOOR.normal) < 1e-9  # a vertical plane
    for cut in cuts:
        assert cut.features.shape == (FEATURES,) and np.isfinite(cut.features).all()
    assert cuts[0].features[2] >= np.log(0.025)  # the strip it leaves empty: about 3 cm


def test_a_cluster_is_cut_only_where_the_judge_finds_two(two_boxes_cloud: tuple) -> None:
    points, box = two_boxes_cloud
    rows = np.arange(len(points))
    assert [len(r) for r in split_touching(points, [rows], FLOOR, sure_judge("one"))] == [len(rows)]
    parts = split_touching(points, [rows], FLOOR, sure_judge("two"))
    assert 2 <= len(parts) <= 4  # each part judged again, once
    assert np.array_equal(np.sort(np.concatenate(parts)), rows)
    for part in parts:  # no part holds both boxes
        assert len(np.unique(box[part])) == 1
    small = rows[:100]  # under MIN_POINTS: not cut
    assert len(split_touching(points, [small], FLOOR, sure_judge("two"))) == 1


def test_the_judge_survives_its_file_and_the_shipped_one_loads(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    network = FeatureNetwork(rng.normal(size=FEATURES), rng.uniform(0.5, 2, FEATURES),
                             rng.normal(size=(FEATURES, 4)), rng.normal(size=4),
                             rng.normal(size=(4, 2)), rng.normal(size=2))  # fmt: skip
    judge = CutJudge(network, 0.7, {"scenes": 1})
    path = tmp_path / "judge.json"
    path.write_text(json.dumps(judge.to_dict()))
    back = load_cut_judge(path)
    x = rng.normal(size=(5, FEATURES))
    assert back is not None and back.threshold == 0.7
    np.testing.assert_allclose(back.probabilities(x), judge.probabilities(x), atol=1e-5)
    assert ((judge.probabilities(x) > 0) & (judge.probabilities(x) < 1)).all()
    path.write_text(json.dumps({**judge.to_dict(), "classes": ["a", "b"]}))
    with pytest.raises(ValueError, match="classes"):
        load_cut_judge.__wrapped__(path)
    assert load_cut_judge(tmp_path / "none.json") is None
    shipped = load_cut_judge()
    assert shipped is not None and 0.5 <= shipped.threshold <= 1.0
    assert shipped.network.mean.shape == (FEATURES,)


@pytest.fixture(scope="module")
def touching_boxes() -> Scene:
    box = boxes_shape([((0, 0, 0), (0.5, 0.6, 0.4))])  # 0.455 m wide at 0.4 m a unit
    return make_test_scene([(box, 0.4, -0.25, 3.0, 0.0), (box, 0.4, 0.25, 3.0, 0.0)])


def test_the_segmentation_cuts_touching_objects_where_switched_on(
    touching_boxes: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two boxes 4.5 cm apart are one cluster; a judge that finds two in it cuts them apart
    (each part of one box), and ``split_touching=False`` leaves them one."""
    given = from_depth(touching_boxes.depth, touching_boxes.intrinsics)
    labels = touching_boxes.labels.ravel()[given.indices]
    (whole,) = segment(given.points, SegmentOptions(split_touching=False)).objects
    assert set(np.unique(labels[whole])) == {1, 2}
    monkeypatch.setattr(segment_module, "load_cut_judge", lambda: sure_judge("two"))
    parts = segment(given.points).objects
    assert len(parts) >= 2
    # a judge that always finds two cuts each part once more: the parts are each mostly of
    # one box, both boxes among them, and 95% of the points lie with their own box's
    owners = [int(np.bincount(labels[part]).argmax()) for part in parts]
    assert set(owners) == {1, 2}
    kept = sum(int(np.bincount(labels[part]).max()) for part in parts)
    assert kept >= 0.95 * sum(len(part) for part in parts)
    assert len(segment(given.points, SegmentOptions(split_touching=False)).objects) == 1


def test_the_threshold_cuts_at_most_its_share_of_one_object_clusters() -> None:
    weights = FeatureNetwork(np.zeros(2), np.ones(2), np.array([[1.0], [0.0]]), np.zeros(1),
                             np.array([[-4.0, 4.0]]), np.zeros(2))  # fmt: skip
    judge = CutJudge(weights, 1.0, {})  # the chance of two rises with the first feature
    rng = np.random.default_rng(1)
    x = rng.normal(size=(2000, 2))
    labels = [f"{k // 5}:one" for k in range(2000)]  # 400 clusters of 5 cuts
    threshold, clusters = touching_cut_fit.cut_threshold(judge, x, labels)
    best = judge.probabilities(x).reshape(400, 5).max(1)
    assert clusters == 400
    assert (best >= threshold).sum() <= 2 < (best >= threshold - 1e-3).sum()


def test_samples_of_several_kinds_of_scenes_keep_their_clusters_apart() -> None:
    """Each kind's clusters are numbered from 0: joined, cluster 0 of the usual scenes and
    cluster 0 of the camera's are two clusters for the threshold; the fit's kinds are the usual
    scenes touching and apart, then the same by the camera, with things and a wall."""
    usual = (np.zeros((3, 2)), ["0:one", "0:one", "1:two"])
    camera = (np.ones((2, 2)), ["0:one", "1:one"])
    features, labels = touching_cut_fit.joined([usual, camera])
    assert features.shape == (5, 2) and labels[3] == "1.0:one"
    judge = CutJudge(FeatureNetwork(np.zeros(2), np.ones(2), np.array([[1.0], [0.0]]),
                                    np.zeros(1), np.array([[-4.0, 4.0]]), np.zeros(2)), 1.0, {})  # fmt: skip
    assert touching_cut_fit.cut_threshold(judge, features, labels)[1] == 3  # 0.0, 1.0, 1.1
    assert touching_cut_fit.fitting_kinds(None) == [(True, {}), (False, {})]
    by_camera = touching_cut_fit.fitting_kinds("kinect_v2")[2:]
    assert [t for t, _ in by_camera] == [True, False]
    assert all(k["sensor"] == "kinect_v2" and k["distractors"] and k["against_wall"]
               for _, k in by_camera)  # fmt: skip
    assert touching_cut_fit.TouchingCutFit().sensor == "kinect_v2"
    assert touching_cut_fit.TouchingCutFit(sensor="none").sensor is None
    with pytest.raises(ValueError, match="unknown camera"):
        touching_cut_fit.TouchingCutFit(sensor="kinect_v9")


def test_the_fit_learns_which_cuts_part_two_objects(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    two = rng.random(1200) < 0.3
    features = rng.normal(size=(1200, FEATURES))
    features[:, 0] += np.where(two, 3.0, 0.0)  # an empty strip tells them apart
    labels = [f"{k}:{'two' if t else 'one'}" for k, t in enumerate(two)]
    samples, check = tmp_path / "samples.npz", tmp_path / "check.npz"
    np.savez(samples, features=features, labels=np.array(labels))
    plain = rng.normal(size=(400, FEATURES))
    np.savez(check, features=plain, labels=np.array([f"{k}:one" for k in range(400)]))
    out = tmp_path / "judge.json"
    fitted_by_cli = CliRunner().invoke(app, ["fit", "touching-cut", "--samples", str(samples),
                                             "--threshold-samples", str(check), "--epochs", "200",
                                             "--out", str(out)])  # fmt: skip
    assert fitted_by_cli.exit_code == 0, fitted_by_cli.output
    judge = load_cut_judge(out)
    assert judge is not None and judge.fit["threshold"]["clusters"] == 400
    assert ((judge.probabilities(features) >= 0.5) == two).mean() > 0.9
    assert (judge.probabilities(plain) >= judge.threshold).mean() <= 0.005


def test_degenerate_clusters_get_no_cut_and_no_error() -> None:
    """A cluster whose points all coincide, or stand on one vertical line, has no side to cut
    off; a flat row along the floor can be cut, and its features stay finite."""
    same = np.tile([[0.1, 1.0, 3.0]], (400, 1))
    pole = np.stack([np.zeros(400), np.linspace(0.5, 1.5, 400), np.full(400, 3.0)], 1)
    assert cut_candidates(same, FLOOR) == [] and cut_candidates(pole, FLOOR) == []
    row = np.stack([np.linspace(-1, 1, 400), np.full(400, 1.2), np.full(400, 3.0)], 1)
    for cut in cut_candidates(row, FLOOR):
        assert np.isfinite(cut.features).all()
    rows = np.arange(400)
    assert len(split_touching(same, [rows], FLOOR, sure_judge("two"))) == 1
    rng = np.random.default_rng(0)  # rounded clouds, through and below the floor: finite
    for _ in range(30):
        cloud = np.round(rng.normal(size=(int(rng.integers(200, 2000)), 3)), 1)
        for cut in cut_candidates(cloud, FLOOR):
            assert np.isfinite(cut.features).all()
