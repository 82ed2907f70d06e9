"""The exported classifier graph (canonicaliser + classifier) against torch, and the loader
telling it apart from the pose models."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from cls_helpers import CLASSES, randomised, tiny_classifier

from itnet.export.classifier_export import (
    choose_threshold,
    export_classifier,
    fused_probabilities,
    same_transformer,
)
from itnet.model_card import ClassifierCard
from itnet.pose.runtime import (
    LoadedClassifier,
    LoadedModel,
    ModelLoadError,
    load_all,
    load_any,
    load_model,
)


@pytest.mark.parametrize(
    ("transformer", "iterations", "regularizer"),
    [("none", 1, 0.0), ("tnet", 2, 0.001), ("itnet", 2, 0.0)],
)
def test_untrained_classifier_exports_and_matches_torch(
    tmp_path: Path, transformer: str, iterations: int, regularizer: float
) -> None:
    net = randomised(tiny_classifier(transformer, iterations, regularizer=regularizer), 7)
    card = ClassifierCard(classes=CLASSES, points=100)
    loaded = load_any(export_classifier(net, card, tmp_path / "c.onnx"), warm_up=False)
    assert isinstance(loaded, LoadedClassifier) and loaded.card.classes == CLASSES
    x = torch.randn(5, 100, 3, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        expected = torch.softmax(net(x)[0], -1).numpy()
    got = loaded.probabilities(x.numpy())
    assert got.shape == (5, 3)
    np.testing.assert_allclose(got, expected, atol=2e-5)
    np.testing.assert_allclose(got.sum(1), 1.0, atol=1e-5)
    assert np.ptp(got, axis=0).max() > 1e-3  # the clouds get different answers: a real graph


def test_untrained_local_classifier_exports_and_matches_torch(tmp_path: Path) -> None:
    """The local head folded for the graph: BatchNorm scales of both signs (a negative one must
    not turn the neighbours' max into a min), a canonicaliser on the first points."""
    net = randomised(
        tiny_classifier("itnet", 2, head="local", local_channels=(8, 16, 32), neighbours=5), 3
    )
    with torch.no_grad():
        for layer in net.classifier.layers:
            layer.norm.weight[::2] *= -1
    card = ClassifierCard(classes=CLASSES, points=100, canonical_points=40, head="local")
    loaded = load_any(export_classifier(net, card, tmp_path / "c.onnx"), warm_up=False)
    assert isinstance(loaded, LoadedClassifier) and loaded.card.head == "local"
    x = torch.randn(5, 100, 3, generator=torch.Generator().manual_seed(4))
    with torch.no_grad():
        assert net.itnet is not None
        from itnet.model.network import apply_pose

        pose = net.itnet(x[:, :40], 2)[-1]
        expected = torch.softmax(net.classifier(apply_pose(pose, x)), -1).numpy()
    got = loaded.probabilities(x.numpy())
    np.testing.assert_allclose(got, expected, atol=2e-5)
    assert np.ptp(got, axis=0).max() > 1e-3
    few = x[:, :3]  # fewer points than neighbours: each point's neighbours are all of them
    with torch.no_grad():
        expected = torch.softmax(net(few)[0], -1).numpy()
    np.testing.assert_allclose(loaded.probabilities(few.numpy()), expected, atol=2e-5)


def test_heads_behind_one_canonicaliser_export_fused(tmp_path: Path) -> None:
    """``fused``: a local head and a PointNet head behind the same canonicaliser, one graph whose
    probabilities are the softmax of their mean log-probability; a head behind another
    canonicaliser is refused."""
    local = randomised(
        tiny_classifier("itnet", 2, head="local", local_channels=(8, 16, 32), neighbours=5), 5
    )
    pointnet = randomised(tiny_classifier("itnet", 2), 6)
    with pytest.raises(ValueError, match="share the transformer"):
        export_classifier(
            local, ClassifierCard(classes=CLASSES), tmp_path / "x.onnx", fused=[pointnet]
        )
    pointnet.itnet.load_state_dict(local.itnet.state_dict())
    card = ClassifierCard(classes=CLASSES, points=100, head="local+pointnet")
    loaded = load_any(
        export_classifier(local, card, tmp_path / "f.onnx", fused=[pointnet]), warm_up=False
    )
    assert isinstance(loaded, LoadedClassifier)
    x = torch.randn(4, 100, 3, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        want = fused_probabilities([local, pointnet], x).numpy()
        alone = [torch.softmax(n(x)[0], -1).numpy() for n in (local, pointnet)]
    got = loaded.probabilities(x.numpy())
    np.testing.assert_allclose(got, want, atol=2e-5)
    assert all(np.abs(got - a).max() > 1e-3 for a in alone)  # neither head alone
    np.testing.assert_allclose(
        got,
        np.exp(np.log(alone).mean(0)) / np.exp(np.log(alone).mean(0)).sum(1, keepdims=True),
        atol=2e-5,
    )


def test_canonicaliser_on_the_first_points_moves_them_all(tmp_path: Path) -> None:
    """``canonical_points`` K: IT-Net finds the pose from the input's first K points, and the
    classifier sees all N moved by it; a cloud of at most K points gets the plain graph's
    answer."""
    from itnet.model.network import apply_pose

    net = randomised(tiny_classifier("itnet", 2), 11)
    card = ClassifierCard(classes=CLASSES, points=100, canonical_points=40)
    loaded = load_any(export_classifier(net, card, tmp_path / "c.onnx"), warm_up=False)
    assert isinstance(loaded, LoadedClassifier) and loaded.card.canonical_points == 40
    x = torch.randn(4, 100, 3, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        assert net.itnet is not None
        pose = net.itnet(x[:, :40], 2)[-1]
        want = torch.softmax(net.classifier(apply_pose(pose, x)), -1).numpy()
        plain = torch.softmax(net(x)[0], -1).numpy()
        small = torch.softmax(net(x[:, :30])[0], -1).numpy()
    got = loaded.probabilities(x.numpy())
    np.testing.assert_allclose(got, want, atol=2e-5)
    assert np.abs(got - plain).max() > 1e-3  # 40 points give another pose than all 100
    np.testing.assert_allclose(loaded.probabilities(x[:, :30].numpy()), small, atol=2e-5)


def test_pose_loader_does_not_take_the_classifier_for_a_pose_model(chair_dir: Path) -> None:
    with pytest.raises(ModelLoadError, match="classifier"):
        load_model(chair_dir / "classifier.onnx", warm_up=False)
    models, classifier = load_all(chair_dir, warm_up=False)
    assert list(models) == ["chair"] and isinstance(models["chair"], LoadedModel)
    assert isinstance(classifier, LoadedClassifier) and classifier.card.kind == "classifier"


def test_threshold_is_the_lowest_that_reaches_the_target() -> None:
    # wrong views up to 0.57: below 0.6 at least 3 of ~27 are wrong (< 95%); from 0.6, none
    p = [0.3, 0.55, 0.56, 0.57, 0.6, 0.7, 0.9] + [0.99] * 20
    ok = [False, False, False, False, True, True, True] + [True] * 20
    assert choose_threshold(p, ok, 0.95) == 0.6
    assert choose_threshold([0.9, 0.8], [True, True], 0.95) == 0.0
    assert choose_threshold([0.99, 0.99], [False, False], 0.95) == 0.95


def test_shipped_classifier_weights_are_the_shipped_classifier() -> None:
    """lab/weights/classifier.pt and classifier_local.pt (the weights a later fine-tune starts
    from: the PointNet head and the local head behind one canonicaliser) give the shipped float32
    graph's probabilities, BatchNorm folded, on noise, a sphere, a box's side and an example scan: the
    cascade's, the PointNet head's alone where it is sure, the two heads fused elsewhere. The
    shipped file stores its weights as float16 (``itnet compact``): each folded weight within a
    relative 2**-11 of the float32 one, so the probabilities agree to 2e-3, the classes exactly."""
    from itnet.cloud_io import read_cloud
    from itnet.model.classify.train import load_classifier
    from itnet.model.network import apply_pose
    from itnet.pose.runtime import LoadedClassifier, default_model_dir, load_any
    from itnet.preprocess import cap_points, estimate_normalization
    from itnet.service.api.routes.examples import examples_dir

    shipped = default_model_dir()
    weights = Path(__file__).resolve().parents[2] / "lab" / "weights"  # not shipped
    net, state = load_classifier(weights / "classifier_local.pt")
    other, other_state = load_classifier(weights / "classifier.pt")
    graph = load_any(shipped / "classifier.onnx", warm_up=False)
    assert isinstance(graph, LoadedClassifier) and "optimizer" not in state
    assert state["classes"] == other_state["classes"] == graph.card.classes
    assert graph.card.head == "pointnet+local" and same_transformer(net, other)
    assert graph.card.cascade == 0.9
    rng = np.random.default_rng(0)
    chair = read_cloud(examples_dir() / "chair_a.ply")
    sphere = rng.normal(size=(graph.card.points, 3))
    side = rng.uniform(-1, 1, (graph.card.points, 3)) * [0.4, 0.5, 0.05]  # a box's flat side
    clouds = [
        rng.normal(size=(graph.card.points, 3)),
        sphere / np.linalg.norm(sphere, axis=1)[:, None],
        side,
    ]
    x = np.stack(
        [
            *(estimate_normalization(c).apply(c) for c in clouds),
            cap_points(estimate_normalization(chair).apply(chair), graph.card.points, rng),
        ]
    ).astype(np.float32)
    seen = graph.card.canonical_points or graph.card.points  # the canonicaliser's points
    with torch.no_grad():
        assert net.itnet is not None
        pose = net.itnet(torch.from_numpy(x[:, :seen]), net.config.iterations)[-1]
        moved = apply_pose(pose, torch.from_numpy(x))
        logs = [torch.log_softmax(n.classifier(moved), -1) for n in (other, net)]
        fused = torch.softmax(torch.stack(logs).mean(0), -1).numpy()
        first = torch.softmax(logs[0], -1).numpy()
    sure = first.max(1) >= graph.card.cascade
    assert sure[-1] and not sure[1:3].any()  # the chair: sure; a sphere, a box's side: not
    got = graph.probabilities(x)
    expected = np.where(sure[:, None], first, fused)
    np.testing.assert_allclose(got, expected, atol=2e-3)
    assert (got.argmax(1) == expected.argmax(1)).all()
    assert graph.card.classes[int(got[-1].argmax())] == "chair"


def test_shipped_upright_classifier_weights_are_the_shipped_upright_classifier() -> None:
    """lab/weights/classifier_upright.pt (what a later fine-tune of the upright classifier starts
    from) gives the shipped upright graph's probabilities on levelled clouds: noise, a box's side
    and an example scan stood up, to the float16 storage of the shipped file."""
    from itnet.cloud_io import read_cloud
    from itnet.model.classify.train import load_classifier
    from itnet.pose.runtime import LoadedClassifier, default_model_dir, load_any
    from itnet.preprocess import cap_points, estimate_normalization
    from itnet.service.api.routes.examples import examples_dir

    weights = Path(__file__).resolve().parents[2] / "lab" / "weights"  # not shipped
    net, state = load_classifier(weights / "classifier_upright.pt")
    graph = load_any(default_model_dir() / "classifier_upright.onnx", warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.upright and "optimizer" not in state
    assert state["classes"] == graph.card.classes and state["config"]["upright"] is not None
    rng = np.random.default_rng(1)
    chair = read_cloud(examples_dir() / "chair_a.ply")
    clouds = [rng.normal(size=(300, 3)), rng.uniform(-1, 1, (300, 3)) * [0.4, 0.5, 0.05], chair]
    x = np.stack(
        [cap_points(estimate_normalization(c).apply(c), graph.card.points, rng) for c in clouds]
    ).astype(np.float32)
    with torch.no_grad():
        expected = torch.softmax(net(torch.from_numpy(x))[0], -1).numpy()
    got = graph.probabilities(x)
    np.testing.assert_allclose(got, expected, atol=2e-3)
    assert (got.argmax(1) == expected.argmax(1)).all()
    other = load_any(default_model_dir() / "classifier.onnx", warm_up=False)
    assert isinstance(other, LoadedClassifier)
    assert np.abs(other.probabilities(x) - got).max() > 0.05  # not any classifier's answers
