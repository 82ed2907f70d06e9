"""A tiny classification run on synthetic classes (a flat plate, a long rod, a ball) in the
ModelNet layout: the loss falls, the result has test metrics, and a rerun resumes."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from cls_helpers import SHAPES, tiny_run

from itnet.model.classify.train import train


@pytest.mark.train
def test_tiny_training_lowers_the_loss_and_resumes(three_classes: Path, tmp_path: Path) -> None:
    config = tiny_run(three_classes, tmp_path)
    result = train(config)
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    losses = [entry["loss"] for entry in log if "loss" in entry]
    assert len(losses) == 6 and np.mean(losses[-2:]) < 0.8 * np.mean(losses[:2]), losses
    assert result["classes"] == ["ball", "plate", "rod"]
    assert result["test"]["scans"] == 3 * 2 * 2 and 0 <= result["test"]["accuracy"] <= 1
    assert set(result["test"]["per_class"]) == {"ball", "plate", "rod"}
    assert np.array(result["test"]["confusion"]).sum() == 12
    # a longer rerun resumes from the last checkpoint instead of starting over
    (tmp_path / "run" / "result.json").unlink()
    train(config.model_copy(update={"steps": 70}))
    starts = [
        e
        for e in map(json.loads, (tmp_path / "run" / "log.jsonl").read_text().splitlines())
        if e.get("event") == "start"
    ]
    assert [s["step"] for s in starts] == [0, 60]


@pytest.mark.train
def test_data_workers_give_the_same_run(three_classes: Path, tmp_path: Path) -> None:
    """--data-workers makes the views in other processes: the same batches (seeded by the
    step), so the same losses as making them in the training loop."""
    losses = {}
    for workers in (0, 2):
        config = tiny_run(three_classes, tmp_path / str(workers), steps=20, eval_every=20,
                          log_every=5, data_workers=workers)  # fmt: skip
        train(config)
        log = (config.out / "log.jsonl").read_text().splitlines()
        losses[workers] = [json.loads(line)["loss"] for line in log if '"loss"' in line]
    assert len(losses[2]) == 4
    assert np.allclose(losses[2], losses[0], rtol=1e-5), losses


@pytest.mark.train
@pytest.mark.parametrize("int8", [False, True])
def test_exported_card_carries_the_accuracy_measured_on_the_graph(
    three_classes: Path, tmp_path: Path, int8: bool
) -> None:
    import onnx
    import torch
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.export.classifier_export import score_graph
    from itnet.model.classify.train import load_classifier
    from itnet.pose.runtime import LoadedClassifier, load_any

    config = tiny_run(three_classes, tmp_path, steps=20, eval_every=10)
    result = train(config)
    out, report = tmp_path / "c.onnx", tmp_path / "export.json"
    weights = tmp_path / "shipped" / "c.pt"
    args = ["classify-export", str(config.out), "--out", str(out), "--report", str(report)]
    args += ["--weights-out", str(weights), "--confusion", str(tmp_path / "confusion.png")]
    run = CliRunner().invoke(app, [*args, *(["--int8"] if int8 else [])])
    assert run.exit_code == 0, run.output
    # the shipped weights: the best checkpoint's network without its optimiser, fine-tunable
    shipped, state = load_classifier(weights)
    best, _ = load_classifier(config.out / "best.pt")
    assert "optimizer" not in state and state["step"] == result["best_step"]
    for name, value in best.state_dict().items():
        assert torch.equal(shipped.state_dict()[name], value), name
    graph = load_any(out, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.classes == ["ball", "plate", "rod"]
    assert graph.card.precision == ("int8" if int8 else "float32")
    ops = {n.op_type for n in onnx.load(str(out)).graph.node}
    assert bool(ops & {"MatMulInteger", "DynamicQuantizeMatMul"}) == int8
    scores = score_graph(graph, config.out)
    assert scores.test_probs.shape == (12, 3) and scores.val_probs.shape[1] == 3
    measured = float((scores.test_probs.argmax(1) == scores.test_labels).mean())
    assert graph.card.accuracy == pytest.approx(measured, abs=1e-4)
    if not int8:  # the float32 graph is torch's network: the same answers on the same views
        assert graph.card.accuracy == pytest.approx(result["test"]["accuracy"], abs=1e-4)
    written = json.loads(report.read_text())
    assert written["card"]["precision"] == graph.card.precision
    assert written["unsure"]["test_views"] == 12
    assert written["unsure"]["accuracy"] == pytest.approx(measured, abs=1e-4)
    # the graph's own per-class accuracy and confusion matrix (rows: the true class), plotted
    confusion = np.array(written["test"]["confusion"])
    assert confusion.sum() == 12 and confusion.trace() == round(12 * measured)
    assert confusion.sum(1).tolist() == [4, 4, 4]
    assert written["test"]["per_class"]["rod"] == pytest.approx(confusion[2, 2] / 4)
    assert (tmp_path / "confusion.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.train
def test_a_graph_served_at_fewer_points_is_measured_at_them(three_classes: Path, tmp_path) -> None:
    """``classify-export --points P`` (fewer than trained): the card's accuracy and threshold are
    the graph's on views of P points, as it will be served, not on the trained views."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.export.classifier_export import score_graph
    from itnet.model.classify.train import ClassifyConfig, run_splits, run_views
    from itnet.pose.runtime import LoadedClassifier, load_any

    config = tiny_run(three_classes, tmp_path, steps=10, eval_every=10)
    train(config)
    out = tmp_path / "few.onnx"
    run = CliRunner().invoke(app, ["classify-export", str(config.out), "--out", str(out),
                                   "--points", "8"])  # fmt: skip
    assert run.exit_code == 0, run.output
    graph = load_any(out, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.points == 8
    seen: list[int] = []
    probabilities = graph.probabilities
    graph.probabilities = lambda x: seen.append(x.shape[1]) or probabilities(x)  # type: ignore[method-assign]
    scores = score_graph(graph, config.out)
    assert set(seen) == {8}
    x, y = run_views(ClassifyConfig.model_validate_json((config.out / "config.json").read_text()),
                     run_splits(config)[1], "test")  # fmt: skip
    assert x.shape[1] == 64  # trained at 64: the card's are the first 8 of each shuffled view
    cut = np.concatenate([probabilities(x[i : i + 1, :8]) for i in range(len(x))])
    np.testing.assert_allclose(scores.test_probs, cut, atol=1e-6)
    measured = float((cut.argmax(1) == y).mean())
    assert graph.card.accuracy == pytest.approx(measured, abs=1e-4)


@pytest.mark.train
def test_a_shipped_checkpoint_reexports_with_a_smaller_canonicaliser(
    three_classes: Path, tmp_path: Path
) -> None:
    """``classify-export CHECKPOINT.pt`` remakes the run from the config the checkpoint keeps:
    the same card as from the run folder; ``--canonical-points`` writes a graph whose
    canonicaliser sees that many points, measured as served."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.pose.runtime import LoadedClassifier, load_any

    config = tiny_run(three_classes, tmp_path, steps=20, eval_every=10)
    train(config)
    weights = tmp_path / "shipped.pt"
    runner = CliRunner()
    exports = {
        "run": [str(config.out), "--weights-out", str(weights)],
        "checkpoint": [str(weights)],
        "fewer": [str(weights), "--canonical-points", "16"],
    }
    cards = {}
    for name, args in exports.items():
        out = tmp_path / f"{name}.onnx"
        run = runner.invoke(app, ["classify-export", *args, "--out", str(out)])
        assert run.exit_code == 0, run.output
        graph = load_any(out, warm_up=False)
        assert isinstance(graph, LoadedClassifier)
        cards[name] = graph.card
    assert cards["checkpoint"] == cards["run"] and cards["run"].canonical_points is None
    assert cards["fewer"].canonical_points == 16
    assert cards["fewer"].training["validation"] != 0.0 and 0.0 < cards["fewer"].accuracy <= 1.0
    bad = tmp_path / "not_a_classifier.pt"
    torch.save({"model": {}}, bad)
    run = runner.invoke(app, ["classify-export", str(bad), "--out", str(tmp_path / "x.onnx")])
    assert run.exit_code == 2 and "not a classifier checkpoint" in run.output


@pytest.mark.train
def test_a_run_with_fewer_canonical_points_trains_and_exports_them(
    three_classes: Path, tmp_path: Path
) -> None:
    """``canonical_points`` in training: IT-Net reads the first K points of views fed in random
    order; the export serves the same K by default, and the float32 graph scores as torch did."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.model.classify.data import fixed_views
    from itnet.model.classify.network import Classifier
    from itnet.model.classify.train import load_classifier, run_splits, run_views
    from itnet.pose.runtime import LoadedClassifier, load_any

    config = tiny_run(three_classes, tmp_path, steps=20, eval_every=10, canonical_points=16)
    result = train(config)
    net, _ = load_classifier(config.out / "best.pt")
    assert net.config.canonical_points == 16
    _, splits = run_splits(config)
    views, _ = run_views(config, splits, "val")  # the fixed views, each in a random order
    raw, _ = fixed_views(splits["val"], config.val_views, config.points, config.seed + 7,
                         config.cache)  # fmt: skip
    assert not np.array_equal(views, raw)
    for seen, scanned in zip(views, raw, strict=True):
        np.testing.assert_array_equal(np.unique(seen, axis=0), np.unique(scanned, axis=0))
    out = tmp_path / "c.onnx"
    run = CliRunner().invoke(app, ["classify-export", str(config.out), "--out", str(out)])
    assert run.exit_code == 0, run.output
    graph = load_any(out, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.canonical_points == 16
    x = np.random.default_rng(4).normal(size=(3, 64, 3)).astype(np.float32)
    every = Classifier(replace(net.config, canonical_points=None))  # the same weights
    every.load_state_dict(net.state_dict())
    with torch.no_grad():
        want = torch.softmax(net(torch.from_numpy(x))[0], -1).numpy()
        other = torch.softmax(every.eval()(torch.from_numpy(x))[0], -1).numpy()
    np.testing.assert_allclose(graph.probabilities(x), want, atol=2e-5)
    assert np.abs(other - want).max() > 1e-6  # 16 points gave another pose than 64
    assert graph.card.accuracy == pytest.approx(result["test"]["accuracy"], abs=1e-4)


def test_balanced_batches_draw_classes_alike() -> None:
    from itnet.model.classify.data import LabelledShapes, training_batch
    from itnet.model.scanner import scan_config
    from itnet.model.shapes import Shape

    rng = np.random.default_rng(4)
    shapes = [Shape(f"s{i}", SHAPES["ball"](rng, 300)) for i in range(40)]
    labels = np.array([0] * 36 + [1] * 3 + [2] * 1)  # 90% / 7.5% / 2.5%
    data = LabelledShapes(shapes, labels)
    configs = [scan_config({})]
    drawn = {False: [], True: []}
    for balanced in (False, True):
        for step in range(6):
            x, y, _ = training_batch(data, 32, 64, np.random.default_rng(step), configs, balanced)
            assert x.shape == (32, 64, 3) and np.isfinite(x).all()
            drawn[balanced] += list(y)
    share = {b: np.bincount(drawn[b], minlength=3) / len(drawn[b]) for b in drawn}
    assert share[False][0] > 0.8  # in proportion to the split
    assert np.all(np.abs(share[True] - 1 / 3) < 0.1), share[True]  # one third each


@pytest.mark.train
def test_balanced_run_keeps_the_best_mean_class_accuracy(tmp_path: Path) -> None:
    import torch

    rng = np.random.default_rng(1)
    for name, count in (("ball", 30), ("plate", 6), ("rod", 6)):  # validation: 6, 1, 1 shapes
        for split, n in (("train", count), ("test", 2)):
            (tmp_path / "data" / name / split).mkdir(parents=True)
            for i in range(n):
                cloud = SHAPES[name](rng, 400) * rng.uniform(0.8, 1.2, 3)
                np.save(tmp_path / "data" / name / split / f"{name}_{i}.npy", cloud)
    config = tiny_run(
        tmp_path / "data", tmp_path, variant="none", steps=40, batch=8, points=32, eval_every=5,
        log_every=5, widths=((8, 16, 32), (16, 8)), balanced=True, validation_fraction=0.2,
    )  # fmt: skip
    train(config)
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    vals = [e for e in log if e.get("event") == "val"]
    assert len(vals) == 8

    def first_best(key: str) -> int:
        return max(vals, key=lambda e: (e[key], -e["step"]))["step"]

    # the two rules disagree on this run, so the test tells them apart
    assert first_best("val_mean_class") != first_best("val_accuracy"), vals
    state = torch.load(tmp_path / "run" / "best.pt", map_location="cpu", weights_only=False)
    assert state["step"] == first_best("val_mean_class")


def test_batches_carry_each_views_up_axis() -> None:
    """A rod standing along the canonical up: in every view its long axis is the ``up`` the
    batch gives, whatever the camera's rotation."""
    from itnet.model.classify.data import LabelledShapes, training_batch
    from itnet.model.scanner import scan_config
    from itnet.model.shapes import Shape

    rng = np.random.default_rng(5)
    rod = Shape("rod", SHAPES["rod"](rng, 600) * [1.0, 1.0, 1.0])
    data = LabelledShapes([rod], np.array([0]))
    x, _, up = training_batch(data, 16, 128, np.random.default_rng(1), [scan_config({})])
    assert up.shape == (16, 3) and np.allclose(np.linalg.norm(up, axis=1), 1.0, atol=1e-5)
    for view, axis in zip(x, up):
        _, _, vt = np.linalg.svd(view - view.mean(0), full_matrices=False)
        assert abs(vt[0] @ axis) > 0.95  # the rod's long axis, up to its sign
    assert np.abs(up @ up.T - np.eye(16)).max() > 0.5  # the views are turned differently


def test_upright_views_stand_the_rod_along_y_within_the_sensor_error() -> None:
    """``upright``: every view levelled by its up direction with up to that error; the rod
    then stands along +y in every view, and the batch's ``up`` is the true up, near +y."""
    from itnet.model.classify.data import LabelledShapes, training_batch
    from itnet.model.scanner import scan_config
    from itnet.model.shapes import Shape

    rng = np.random.default_rng(5)
    rod = Shape("rod", SHAPES["rod"](rng, 600))
    data = LabelledShapes([rod], np.array([0]))
    x, _, up = training_batch(
        data, 16, 128, np.random.default_rng(1), [scan_config({})], upright=5.0
    )
    off = np.degrees(np.arccos(np.clip(up[:, 1], -1, 1)))
    assert off.max() <= 5.0 + 1e-3 and off.max() > 0.5  # tilted by the drawn error
    for view in x:
        _, _, vt = np.linalg.svd(view - view.mean(0), full_matrices=False)
        assert abs(vt[0][1]) > 0.95  # standing along y


def test_fixed_upright_views_are_levelled_by_a_two_degree_off_up(tmp_path: Path) -> None:
    from itnet.model.classify.data import LabelledShapes, fixed_views
    from itnet.model.shapes import Shape
    from itnet.upright import UPRIGHT_EVAL_DEG

    rng = np.random.default_rng(2)
    rod = Shape("rod", SHAPES["rod"](rng, 600))
    data = LabelledShapes([rod], np.array([0]))
    free, _ = fixed_views(data, 8, 128, 3, tmp_path)
    stood, labels = fixed_views(data, 8, 128, 3, tmp_path, upright=UPRIGHT_EVAL_DEG)
    assert stood.shape == free.shape == (8, 128, 3) and (labels == 0).all()
    axes = [np.linalg.svd(v - v.mean(0), full_matrices=False)[2][0] for v in stood]
    tilt = np.degrees(np.arccos(np.clip(np.abs([a[1] for a in axes]), 0, 1)))
    assert tilt.max() < UPRIGHT_EVAL_DEG + 1.5  # the rod's axis: the error, and the scan's noise
    free_axes = [np.linalg.svd(v - v.mean(0), full_matrices=False)[2][0] for v in free]
    assert min(abs(a[1]) for a in free_axes) < 0.9  # unlevelled views lie every which way


def test_fixed_views_from_above_are_their_own_views(tmp_path: Path) -> None:
    """Fixed views from cameras 30-60 degrees over the horizon are scanned so (the scanner's
    tests check the cameras) and cached apart from the views from any direction."""
    from itnet.model.classify.data import LabelledShapes, fixed_views, view_configs
    from itnet.model.shapes import Shape

    rng = np.random.default_rng(3)
    plate = rng.uniform([-1.0, -0.02, -1.0], [1.0, 0.02, 1.0], size=(800, 3))
    data = LabelledShapes([Shape("plate", plate)], np.array([0]))
    above = view_configs(("paper",), (30.0, 60.0))
    assert above[0].elevation == (30.0, 60.0) and view_configs()[0].elevation is None
    seen, labels = fixed_views(data, 6, 128, 5, tmp_path, configs=above)
    assert seen.shape == (6, 128, 3) and (labels == 0).all()
    assert len(list(tmp_path.glob("scans-*.npz"))) == 1
    unlevelled, _ = fixed_views(data, 6, 128, 5, tmp_path, configs=view_configs(("paper",)))
    assert len(list(tmp_path.glob("scans-*.npz"))) == 2  # another cache entry, not the same scans
    assert not np.allclose(seen, unlevelled)


def test_classify_train_refuses_unknown_views_and_bad_elevations() -> None:
    from typer.testing import CliRunner

    from itnet.cli import app

    runner = CliRunner()
    for args, hint in [(["--views", "sideways"], "--views"), (["--elevation", "50,10"], "--elevation"),
                       (["--elevation", "0,90"], "--elevation"), (["--elevation", "ten"], "--elevation")]:  # fmt: skip
        result = runner.invoke(app, ["classify-train", *args, "--steps", "1"])
        assert result.exit_code == 2 and hint in result.output, result.output


def test_up_term_is_zero_standing_and_two_upside_down() -> None:
    """The up-axis term of an untrained IT-Net (identity pose): 1 - u_y, times the weight;
    absent without ``up`` or with weight 0."""
    import torch
    from cls_helpers import tiny_classifier

    points = torch.randn(3, 32, 3)
    up = torch.tensor([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    net = tiny_classifier("itnet", iterations=2, up_weight=0.5).eval()
    with torch.no_grad():  # the last layer of an untrained IT-Net regresses the identity
        _, penalty = net(points, up)
        assert float(penalty) == pytest.approx(0.5 * (0.0 + 2.0 + 1.0) / 3, abs=1e-5)
        assert float(net(points)[1]) == 0.0
        assert float(tiny_classifier("itnet")(points.clone(), up)[1]) == 0.0
    with pytest.raises(ValueError, match="itnet"):
        tiny_classifier("tnet", up_weight=0.5)
    # IT-Net learns from the up term alone: the class loss does not reach it
    logits, _ = net.train()(points, up)
    logits.sum().backward()
    assert all(p.grad is None or not p.grad.any() for p in net.itnet.parameters())
    assert any(p.grad is not None and p.grad.any() for p in net.classifier.parameters())


def _stand(r: np.random.Generator, n: int) -> np.ndarray:
    """A disc on a pole, upright in ModelNet's frame (+z up): its up is plain to see."""
    k = n // 2
    angle, radius = r.uniform(0, 2 * np.pi, k), np.sqrt(r.uniform(0, 1, k))
    disc = np.c_[radius * np.cos(angle), radius * np.sin(angle), 1 + r.normal(0, 0.01, k)]
    pole = np.c_[r.normal(0, 0.03, (n - k, 2)), r.uniform(-1, 1, n - k)]
    return np.r_[disc, pole]


def _cone(r: np.random.Generator, n: int) -> np.ndarray:
    """A cone's surface, apex up (+z)."""
    height, angle = r.uniform(0, 1, n), r.uniform(0, 2 * np.pi, n)
    ring = 0.8 * (1 - height)
    return np.c_[ring * np.cos(angle), ring * np.sin(angle), 2 * height - 1]


@pytest.mark.train
def test_up_weight_teaches_itnet_to_stand_views_up(tmp_path: Path) -> None:
    """Trained with the up-axis term on shapes whose up shows (a disc on a pole, a cone), IT-Net
    learns to turn the views upright: the logged term falls from ~1 (random) to well under."""
    rng = np.random.default_rng(0)
    for name, make in (("stand", _stand), ("cone", _cone)):
        for split, count in (("train", 8), ("test", 2)):
            (tmp_path / "data" / name / split).mkdir(parents=True)
            for i in range(count):
                cloud = make(rng, 400) * rng.uniform(0.8, 1.2, 3)
                np.save(tmp_path / "data" / name / split / f"{name}_{i}.npy", cloud)
    config = tiny_run(tmp_path / "data", tmp_path, steps=150, eval_every=150, log_every=25,
                      up_weight=1.0)  # fmt: skip
    train(config)
    log = [json.loads(line) for line in (config.out / "log.jsonl").read_text().splitlines()]
    terms = [e["penalty"] for e in log if "penalty" in e]
    assert len(terms) == 6 and terms[0] > 0.7 and terms[-1] < 0.6 * terms[0], terms
    assert json.loads((config.out / "config.json").read_text())["up_weight"] == 1.0


@pytest.mark.train
def test_without_up_weight_the_loss_is_the_class_loss_alone(
    three_classes: Path, tmp_path: Path
) -> None:
    config = tiny_run(three_classes, tmp_path, steps=10, eval_every=10, log_every=5)
    train(config)
    log = (config.out / "log.jsonl").read_text().splitlines()
    assert [json.loads(line)["penalty"] for line in log if '"penalty"' in line] == [0.0, 0.0]


@pytest.mark.train
def test_init_seed_trains_another_network_on_the_same_split(
    three_classes: Path, tmp_path: Path
) -> None:
    """--init-seed: another initialisation and other batches (other losses), the same
    validation shapes and views (so two members of an ensemble are validated alike)."""
    from itnet.model.classify.train import run_splits, run_views

    losses, views = {}, {}
    for seed in (None, 1):
        config = tiny_run(three_classes, tmp_path / str(seed), steps=10, eval_every=10,
                          log_every=5, init_seed=seed)  # fmt: skip
        train(config)
        log = (config.out / "log.jsonl").read_text().splitlines()
        losses[seed] = [json.loads(line)["loss"] for line in log if '"loss"' in line]
        views[seed] = run_views(config, run_splits(config)[1], "val")
    assert not np.allclose(losses[None], losses[1])
    np.testing.assert_array_equal(views[None][0], views[1][0])
    np.testing.assert_array_equal(views[None][1], views[1][1])


@pytest.mark.train
def test_an_upright_run_exports_an_upright_card_measured_fused_with_the_other(
    three_classes: Path, tmp_path: Path
) -> None:
    """``--upright``: the run trains and validates on levelled views; its export is an upright
    classifier whose card's accuracy is the pair's as served (fused with ``--beside``), which
    the service then loads beside the other."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.export.classifier_export import score_graph
    from itnet.pose.runtime import load_all, load_any

    free = tiny_run(three_classes, tmp_path / "free", steps=10, eval_every=10)
    train(free)
    upright = tiny_run(three_classes, tmp_path / "up", steps=10, eval_every=10, upright=5.0)
    train(upright)
    models = tmp_path / "models"
    runner = CliRunner()
    exported = runner.invoke(
        app, ["classify-export", str(free.out), "--out", str(models / "classifier.onnx")]
    )
    assert exported.exit_code == 0, exported.output
    beside = models / "classifier.onnx"
    out = models / "classifier_upright.onnx"
    exported = runner.invoke(
        app, ["classify-export", str(upright.out), "--out", str(out), "--beside", str(beside)]
    )
    assert exported.exit_code == 0, exported.output
    graph, partner = load_any(out, warm_up=False), load_any(beside, warm_up=False)
    assert graph.card.upright and "fused with classifier.onnx" in graph.card.evaluation
    alone, fused = score_graph(graph, upright.out), score_graph(graph, upright.out, partner)
    measured = float((fused.test_probs.argmax(1) == fused.test_labels).mean())
    assert graph.card.accuracy == pytest.approx(measured, abs=1e-4)
    assert not np.allclose(alone.test_probs, fused.test_probs)  # the partner took part
    np.testing.assert_allclose(fused.test_probs.sum(1), 1.0, atol=1e-6)
    # the service's loader pairs them (a pose model beside, as every model folder has)
    from itnet.export.onnx_export import export_step
    from itnet.model.network import ITNet
    from itnet.model_card import ModelCard

    export_step(ITNet(), ModelCard(name="rod", category="rod", points=64), models / "rod.onnx")
    _, classifier = load_all(models, warm_up=False)
    assert classifier is not None and classifier.upright is not None
    assert classifier.upright.card.upright and not classifier.card.upright


@pytest.mark.train
def test_moving_average_competes_on_validation_and_resumes(
    three_classes: Path, tmp_path: Path
) -> None:
    """``ema``: every validation scores the raw weights and their moving average; best.pt holds
    the winner's weights (it computes the logged score), last.pt the average for a resume.
    ``label_smoothing`` changes the loss the run logs."""
    from itnet.model.classify.train import load_classifier, metrics, predict, run_splits, run_views

    config = tiny_run(three_classes, tmp_path / "ema", steps=40, eval_every=20, ema=0.9,
                      label_smoothing=0.2)  # fmt: skip
    train(config)
    log = [json.loads(line) for line in (config.out / "log.jsonl").read_text().splitlines()]
    vals = [e for e in log if e.get("event") == "val"]
    assert [v["step"] for v in vals] == [20, 40]
    for v in vals:
        assert v["val_accuracy"] == max(v["raw_val_accuracy"], v["ema_val_accuracy"])
        assert v["weights"] == ("ema" if v["ema_val_accuracy"] > v["raw_val_accuracy"] else "raw")
    net, state = load_classifier(config.out / "best.pt")
    classes, splits = run_splits(config)
    val_x, val_y = run_views(config, splits, "val")
    score = metrics(predict(net, val_x), val_y, classes)["accuracy"]
    assert score == pytest.approx(state["best"]["val_accuracy"])
    last = torch.load(config.out / "last.pt", weights_only=False)
    assert "ema" in last and last["step"] == 40
    averaged = {k[len("module.") :]: v for k, v in last["ema"].items() if k.startswith("module.")}
    assert any(not torch.equal(averaged[k], last["model"][k]) for k in last["model"])
    # the same start and batches without smoothing log another loss
    plain = tiny_run(three_classes, tmp_path / "plain", steps=10, eval_every=10, log_every=10)
    smooth = plain.model_copy(update={"out": tmp_path / "smooth" / "run", "label_smoothing": 0.2})
    first = {}
    for run in (plain, smooth):
        train(run)
        entries = (run.out / "log.jsonl").read_text().splitlines()
        first[run.label_smoothing] = next(json.loads(e)["loss"] for e in entries if '"loss"' in e)
    assert first[0.2] != pytest.approx(first[0.0], rel=1e-3)


@pytest.mark.train
def test_a_run_can_hold_the_test_split_back_until_it_is_exported(
    three_classes: Path, tmp_path: Path
) -> None:
    """``hold_test``: the run validates as usual and ends without a test measurement; exporting
    it measures the graph on the test split, as for any run."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.pose.runtime import LoadedClassifier, load_any

    config = tiny_run(three_classes, tmp_path, steps=10, eval_every=10, hold_test=True)
    result = train(config)
    assert result["test"] is None and result["val"]["scans"] > 0
    done = json.loads((config.out / "log.jsonl").read_text().splitlines()[-1])
    assert done == {"event": "done", "test_accuracy": None}
    out = tmp_path / "held.onnx"
    run = CliRunner().invoke(app, ["classify-export", str(config.out), "--out", str(out)])
    assert run.exit_code == 0, run.output
    assert "torch: not measured" in run.output
    graph = load_any(out, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and 0 <= graph.card.accuracy <= 1


def test_views_by_a_depth_camera_take_each_class_at_its_real_size(tmp_path: Path) -> None:
    from itnet.model.categories import real_radius_m
    from itnet.model.classify.data import LabelledShapes, fixed_views, training_batch, view_configs
    from itnet.model.shapes import Shape

    rng = np.random.default_rng(5)
    shapes = [Shape(f"s{i}", SHAPES["ball"](rng, 400)) for i in range(4)]
    data = LabelledShapes(shapes, np.array([0, 1, 1, 0]), ("bed", "night_stand"))
    clean, camera = view_configs(("occluded", "occluded+kinect_v2"))
    assert clean.sensor == "clean" and camera.sensor == "kinect_v2"
    assert data.sized(clean, 1) is clean  # a render has no size
    assert data.sized(camera, 0).radius_m == tuple(real_radius_m("bed"))
    assert data.sized(camera, 1).radius_m == tuple(real_radius_m("night_stand"))
    x, y = fixed_views(data, 2, 64, 0, tmp_path, configs=[camera])
    assert x.shape == (8, 64, 3) and np.isfinite(x).all()
    assert sorted(y.tolist()) == [0, 0, 0, 0, 1, 1, 1, 1]  # every shape's views, per class
    x, y, _ = training_batch(data, 8, 64, np.random.default_rng(1), [camera])
    assert x.shape == (8, 64, 3) and np.isfinite(x).all()
    with pytest.raises(ValueError, match="class names"):
        LabelledShapes(shapes, data.labels).sized(camera, 0)
    with pytest.raises(ValueError, match="unknown sensor"):
        view_configs(("occluded+kinect_v9",))
    with pytest.raises(ValueError, match="unknown view rule"):
        view_configs(("sideways",))
    (crop,) = view_configs(("paper+kinect_v2+crop",))
    assert crop.surroundings is not None and crop.elevation is not None
    x, y, up = training_batch(data, 8, 64, np.random.default_rng(2), [crop], upright=5)
    assert x.shape == (8, 64, 3) and np.isfinite(x).all() and np.isfinite(up).all()
    with pytest.raises(ValueError, match="needs a camera"):
        view_configs(("occluded+crop",))
