"""The scene classifier: a cluster's features on the floor, the network and its file, which
classifier it serves, how a scene's objects are named by it, and its fit."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.cli import app
from itnet.geometry import axis_angle_to_matrix
from itnet.model import scene_classifier_fit
from itnet.model.scenes import Scene
from itnet.planes import Plane
from itnet.scene import SceneFinishing, find_objects
from itnet.scene.feature_network import FeatureNetwork
from itnet.scene.pipeline import serving_scene_classifier, shipped_catalog
from itnet.scene.posing import scene_category
from itnet.scene.scene_classifier import (
    OTHER,
    SceneClassifier,
    classifier_graphs,
    cluster_features,
    load_scene_classifier,
)
from itnet.scene.unknown import unknown_reason

UP = np.array([0.0, -1.0, 0.0])  # the camera's y points down
FLOOR = Plane(UP, 1.5)  # 1.5 m below the camera
CLASSES = 10


def front_face(width: float, height: float, distance: float, n: int = 4000) -> np.ndarray:
    """A flat face (n, 3) ``width`` across and ``height`` tall, standing on FLOOR ``distance``
    ahead of the camera, facing it."""
    rng = np.random.default_rng(0)
    x = rng.uniform(-width / 2, width / 2, n)
    h = rng.uniform(0, height, n)
    return np.stack([x, 1.5 - h, np.full(n, distance)], axis=1)


def test_a_face_on_the_floor_is_measured_in_metres_seen_from_the_camera() -> None:
    log_p = np.log(np.full(CLASSES, 1 / CLASSES))
    f = cluster_features(front_face(0.8, 1.0, 3.0), log_p, FLOOR, np.zeros(3))
    assert f.shape == (CLASSES + 21,)
    np.testing.assert_allclose(f[:CLASSES], log_p)
    shape = f[CLASSES:]
    assert np.exp(shape[0]) == pytest.approx(0.98, abs=0.01)  # the top's height
    np.testing.assert_allclose(shape[1:7], 1 / 6, atol=0.02)  # evenly up its height
    assert np.exp(shape[7]) == pytest.approx(0.72, abs=0.02)  # width, 5th-95th percentile
    assert np.exp(shape[8]) == pytest.approx(0.02)  # a face has no depth (the floor of 2 cm)
    assert np.exp(shape[13]) == pytest.approx(3.0, abs=0.01)  # its distance along the floor
    assert shape[-1] == pytest.approx(0.5, abs=0.02)  # mean height over the top
    taller = cluster_features(front_face(0.8, 1.6, 3.0), log_p, FLOOR, np.zeros(3))[CLASSES:]
    assert np.exp(taller[0]) == pytest.approx(1.57, abs=0.02)


def test_the_features_turn_with_the_camera_about_up() -> None:
    """An object and the camera turned together about the floor's normal: the same features."""
    log_p = np.log(np.linspace(1, 2, CLASSES) / np.linspace(1, 2, CLASSES).sum())
    rng = np.random.default_rng(1)
    points = front_face(0.6, 0.9, 2.5) + rng.normal(0, 0.05, size=(4000, 3)) * [1, 0, 1]
    turn = axis_angle_to_matrix(UP, 0.7)
    camera = np.zeros(3)
    about = np.array([0.0, 1.5, 0.0])  # a point of the floor's normal through the camera
    turned_points = (points - about) @ turn.T + about
    turned_camera = turn @ (camera - about) + about
    np.testing.assert_allclose(
        cluster_features(turned_points, log_p, FLOOR, turned_camera),
        cluster_features(points, log_p, FLOOR, camera), atol=1e-9,
    )  # fmt: skip


def tiny_classifier(favoured: int, classes: tuple[str, ...], inputs: tuple[str, ...],
                    graphs: tuple[str, str] = ("a", "b"), threshold: float = 0.5) -> SceneClassifier:  # fmt: skip
    """A network that answers ``classes[favoured]`` surely, whatever the features."""
    f, h, c = len(inputs) + 21, 3, len(classes)
    bias = np.zeros(c)
    bias[favoured] = 8.0
    network = FeatureNetwork(np.zeros(f), np.ones(f), np.zeros((f, h)), np.zeros(h),
                             np.zeros((h, c)), bias)  # fmt: skip
    return SceneClassifier(classes, inputs, graphs, network, threshold, {"note": "tiny"})


def test_the_network_answers_probabilities_and_survives_its_file(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    f, h, c = 31, 5, 4
    arrays = FeatureNetwork(rng.normal(size=f), rng.uniform(0.5, 2, f), rng.normal(size=(f, h)),
                            rng.normal(size=h), rng.normal(size=(h, c)), rng.normal(size=c))  # fmt: skip
    net = SceneClassifier(("a", "b", "c", "d"), tuple(f"i{k}" for k in range(10)), ("x", ""),
                          arrays, 0.6, {"scenes": 1})  # fmt: skip
    x = rng.normal(size=(7, f))
    p = net.probabilities(x)
    assert p.shape == (7, 4) and np.allclose(p.sum(1), 1) and (p > 0).all()
    z = np.tanh(((x - arrays.mean) / arrays.scale) @ arrays.hidden + arrays.hidden_bias)
    np.testing.assert_array_equal(p.argmax(1), (z @ arrays.output + arrays.output_bias).argmax(1))
    path = tmp_path / "net.json"
    path.write_text(json.dumps(net.to_dict()))
    back = load_scene_classifier(path)
    assert back is not None and back.classes == net.classes and back.graphs == net.graphs
    np.testing.assert_allclose(back.probabilities(x), p, atol=1e-5)
    assert load_scene_classifier(tmp_path / "none.json") is None


def test_the_shipped_file_serves_the_shipped_classifier_and_no_other() -> None:
    catalog = shipped_catalog()
    assert catalog.classifier is not None
    shipped = load_scene_classifier()
    assert shipped is not None and shipped.graphs == classifier_graphs(catalog.classifier)
    assert serving_scene_classifier(catalog) is shipped
    assert serving_scene_classifier(catalog, False) is None
    other = replace(shipped, graphs=("0" * 64, shipped.graphs[1]))
    assert serving_scene_classifier(catalog, other) is None
    assert "monitor" not in shipped.classes and {"desk", "dresser", "chair"} <= set(shipped.classes)
    assert 0 < shipped.threshold < 1


def test_a_scene_object_is_named_by_the_scene_classifier_where_it_names_the_categories() -> None:
    catalog = shipped_catalog()
    assert catalog.classifier is not None
    inputs = tuple(catalog.classifier.card.classes)
    points = front_face(0.5, 0.7, 3.0, 1500)
    sure = tiny_classifier(1, ("bed", "desk", "sofa"), inputs, threshold=0.5)
    seen = scene_category(catalog, points, UP, np.zeros(3), floor=FLOOR, scene_classifier=sure)
    assert seen.category == "desk" and not seen.unsure
    assert seen.candidates[0]["category"] == "desk" and len(seen.candidates) == 3
    doubting = replace(sure, threshold=1.0)
    assert scene_category(catalog, points, UP, np.zeros(3), floor=FLOOR,
                          scene_classifier=doubting).unsure  # fmt: skip
    only = scene_category(catalog, points, UP, np.zeros(3), categories=frozenset({"bed", "sofa"}),
                          floor=FLOOR, scene_classifier=sure)  # fmt: skip
    assert only.category in {"bed", "sofa"}  # renormalised over what the object may be
    assert sum(c["probability"] for c in only.candidates) == pytest.approx(1.0, abs=1e-5)
    monitor = scene_category(catalog, points, UP, np.zeros(3), categories=frozenset({"monitor"}),
                             floor=FLOOR, scene_classifier=sure)  # fmt: skip
    assert monitor.category == "monitor"  # it names no monitor: the classifier and the height


def test_find_objects_names_by_the_scene_classifier_unless_told_not_to(
    monkeypatch: pytest.MonkeyPatch, chair_scene: Scene
) -> None:
    catalog = shipped_catalog()
    assert catalog.classifier is not None
    inputs = tuple(catalog.classifier.card.classes)
    sofa = tiny_classifier(1, ("bed", "sofa"), inputs, classifier_graphs(catalog.classifier))
    # without the category recheck, which may weigh a chair posed as a sofa against a bed
    (obj,) = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=1000,
                          scene_classifier=sofa, finishing=SceneFinishing(recheck=False)).objects  # fmt: skip
    assert obj.category == "sofa" and obj.run is not None and obj.run["model"] == "sofa"
    (plain,) = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=1000,
                            scene_classifier=False).objects  # fmt: skip
    assert plain.category == "chair"


def separable_samples(
    names: tuple[str, ...], rng: np.random.Generator
) -> tuple[np.ndarray, list[str]]:
    """600 clusters' features, each of one of ``names`` drawn at random, told apart by the
    top's height alone (2 apart a class), and their labels."""
    labels = [names[k] for k in rng.integers(0, len(names), 600)]
    features = rng.normal(size=(600, CLASSES + 21))
    features[:, CLASSES] += [2.0 * names.index(name) for name in labels]
    return features, labels


def fitted_by_cli(
    tmp_path: Path, features: np.ndarray, labels: list[str], check: list[int]
) -> SceneClassifier:
    """The scene classifier ``itnet fit scene-classifier`` fits on the samples, its threshold
    chosen on the rows ``check`` of them."""
    samples, checked = tmp_path / "samples.npz", tmp_path / "check.npz"
    np.savez(samples, features=features, labels=np.array(labels))
    np.savez(checked, features=features[check], labels=np.array([labels[k] for k in check]))
    out = tmp_path / "scene_classifier.json"
    done = CliRunner().invoke(app, ["fit", "scene-classifier", "--samples", str(samples),
                                    "--threshold-samples", str(checked), "--epochs", "200",
                                    "--out", str(out)])  # fmt: skip
    assert done.exit_code == 0, done.output
    fitted = load_scene_classifier(out)
    assert fitted is not None
    return fitted


def test_the_fit_learns_the_categories_from_features_and_sets_the_threshold(
    tmp_path: Path,
) -> None:
    names = ("chair", "desk", "dresser")
    features, labels = separable_samples(names, np.random.default_rng(3))
    fitted = fitted_by_cli(tmp_path, features, labels, list(range(200)))
    assert fitted.classes == names
    named = np.array(names)[fitted.probabilities(features).argmax(1)]
    assert (named == np.array(labels)).mean() > 0.9
    assert fitted.fit["threshold"]["clusters"] == 200 and 0 < fitted.threshold <= 1
    assert fitted.graphs == classifier_graphs(shipped_catalog().classifier)  # type: ignore[arg-type]


def test_the_threshold_is_the_lowest_with_the_precision_above_it() -> None:
    p = np.array([0.99, 0.9, 0.8, 0.7, 0.6, 0.5])
    right = np.array([True, True, True, True, False, False])
    assert scene_classifier_fit.precision_threshold(p, right, 0.95) == 0.7
    assert scene_classifier_fit.precision_threshold(p, right, 0.6) == 0.5  # 4 of 6 right
    assert scene_classifier_fit.precision_threshold(p, ~right, 0.95) == 1.0  # none is enough


def test_a_cluster_likelier_none_of_the_categories_is_answered_unknown_not_ours(
    chair_scene: Scene,
) -> None:
    catalog = shipped_catalog()
    assert catalog.classifier is not None
    inputs = tuple(catalog.classifier.card.classes)
    points = front_face(0.5, 0.7, 3.0, 1500)
    other = tiny_classifier(2, ("bed", "desk", OTHER), inputs, threshold=0.5)
    seen = scene_category(catalog, points, UP, np.zeros(3), floor=FLOOR, scene_classifier=other)
    assert seen.category in {"bed", "desk"} and seen.other > 0.99  # named among the categories
    assert sum(c["probability"] for c in seen.candidates) == pytest.approx(1.0, abs=1e-5)
    assert unknown_reason(seen.category, seen.probability, points, -UP, seen.other) == "not_ours"
    ours = tiny_classifier(1, ("bed", "desk", OTHER), inputs, threshold=0.5)
    seen = scene_category(catalog, points, UP, np.zeros(3), floor=FLOOR, scene_classifier=ours)
    assert seen.category == "desk" and seen.other < 0.01
    assert unknown_reason("desk", seen.probability, points, -UP, seen.other) is None
    # end to end: the scene's chair, taken for a thing of no category, is answered unknown
    graphs = classifier_graphs(catalog.classifier)
    served = replace(other, graphs=graphs, classes=("chair", "sofa", OTHER))
    (obj,) = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=1000,
                          scene_classifier=served).objects  # fmt: skip
    assert obj.category is None and obj.unknown == "not_ours" and obj.pose is None
    (named,) = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=1000,
                            scene_classifier=served,
                            finishing=SceneFinishing(unknown=False, recheck=False)).objects  # fmt: skip
    assert named.category in {"chair", "sofa"}  # every cluster named where asked


def test_the_fit_learns_things_of_no_category_apart(tmp_path: Path) -> None:
    names = ("chair", "desk", OTHER)
    features, labels = separable_samples(names, np.random.default_rng(4))
    ours = [k for k, name in enumerate(labels) if name != OTHER][:200]  # validation: no things
    fitted = fitted_by_cli(tmp_path, features, labels, ours)
    assert fitted.classes == tuple(sorted(names))
    assert fitted.fit["threshold"]["named_right"] > 0.9  # the categories' shares of the rest
    things = features[[k for k, name in enumerate(labels) if name == OTHER]]
    assert (fitted.probabilities(things).argmax(1) == fitted.classes.index(OTHER)).mean() > 0.9
    config = scene_classifier_fit.SceneClassifierFit(sensors="default,kinect_v2")
    assert config.cameras() == (None, "kinect_v2")
    refused = CliRunner().invoke(app, ["fit", "scene-classifier", "--sensors", "kinect_v9"])
    assert refused.exit_code == 2 and "kinect_v9" in refused.output


def test_clusters_that_are_no_one_object_are_learned_as_other() -> None:
    labels = np.zeros((4, 10), dtype=np.int64)
    labels[:, 0:4], labels[:, 5:8] = 1, 2  # a chair, then a thing of no category
    flat = np.arange(40).reshape(4, 10)
    chair = flat[:, 0:4].ravel()
    thing = flat[:, 5:8].ravel()
    wall = flat[:, 8:10].ravel()  # floor or wall only
    joined = np.concatenate([flat[:, 2:4].ravel(), flat[:, 4].ravel(), flat[:, 5:7].ravel()])
    piece = flat[0:2, 0:2].ravel()  # a quarter of the chair: its own, poorly matched
    returned = [chair, thing, wall, joined, piece]
    named = ["chair", OTHER]
    assert scene_classifier_fit.cluster_labels(returned, labels, named) == {0: "chair", 1: OTHER}
    assert scene_classifier_fit.cluster_labels(returned, labels, named, no_one_object=True) == {
        0: "chair", 1: OTHER, 2: OTHER, 3: OTHER,
    }  # fmt: skip
