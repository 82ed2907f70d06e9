"""The learned verifier (model/verifier.py): its training batches, its command, its export, how
the service loads it beside its category's pose models, and verify anchoring fused runs on the
run it finds likeliest instead of running the probes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from itnet.basin import canonical_points, likeliest_run
from itnet.cli import app
from itnet.fusion import fuse_poses
from itnet.geometry import random_rotation, rotation_error_deg
from itnet.model.verifier import PoseRuns, VerifierConfig, cube_turns, hypothesis_batch
from itnet.pose.runtime import LoadedVerifier, ModelLoadError, load_all, load_any, load_model
from itnet.preprocess import pose_from_normalized
from tests.pose_runs import run_with

SHIPPED = Path(__file__).resolve().parents[2] / "itnet" / "models"

runner = CliRunner()


def _best_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising |R a_i - b_i| over centred point sets (N, 3) (Kabsch)."""
    a, b = a - a.mean(0), b - b.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def test_cube_turns_are_the_24_rotations_identity_first():
    turns = cube_turns()
    assert turns.shape == (24, 3, 3) and np.allclose(turns[0], np.eye(3))
    assert np.allclose(turns @ turns.transpose(0, 2, 1), np.eye(3))
    assert np.allclose(np.linalg.det(turns), 1.0)
    assert len({tuple(np.round(t).astype(int).ravel()) for t in turns}) == 24


def _runs(rng: np.random.Generator, scans: int = 6, k: int = 3) -> PoseRuns:
    points = rng.normal(size=(scans, k, 64, 3)) * [1.0, 0.6, 0.3]
    truths = np.tile(np.eye(4), (scans, 1, 1))
    truths[:, :3, :3] = random_rotation(rng, scans)
    truths[:, :3, 3] = rng.normal(size=(scans, 3)) * 0.1
    poses = np.repeat(truths[:, None], k, axis=1)
    poses[:, 1:, :3, :3] = random_rotation(rng, scans * (k - 1)).reshape(scans, k - 1, 3, 3)
    errors = rotation_error_deg(poses[..., :3, :3], truths[:, None, :3, :3])
    return PoseRuns(points.astype(np.float16), poses.astype(np.float32),
                    errors.astype(np.float32), truths.astype(np.float32))  # fmt: skip


def test_a_batch_of_the_runs_themselves_is_labelled_by_their_errors(rng):
    runs = _runs(rng)
    config = VerifierConfig(pose_model=Path("x.onnx"), batch=64, synthetic=0.0)
    x, labels, weights = hypothesis_batch(runs, config, "none", np.random.default_rng(3))
    pick = np.random.default_rng(3)
    s, k = pick.integers(6, size=64), pick.integers(3, size=64)
    expected = canonical_points(runs.points[s, k].astype(np.float32), runs.poses[s, k])
    assert np.allclose(x, expected, atol=1e-5)
    assert np.array_equal(labels, (runs.errors[s, k] < 15).astype(np.float32))
    band = (runs.errors[s, k] >= 15) & (runs.errors[s, k] <= 25)
    assert np.array_equal(weights, (~band).astype(np.float32))
    assert labels.sum() > 0 and (1 - labels).sum() > 0


def test_knocked_off_truths_are_right_within_10_degrees_and_wrong_beyond_25(rng):
    """Each synthetic hypothesis, recovered from the points it puts (Kabsch against the truth's
    placement), is as far from the truth as its label says."""
    runs = _runs(rng)
    config = VerifierConfig(pose_model=Path("x.onnx"), batch=400, synthetic=1.0)
    x, labels, weights = hypothesis_batch(runs, config, "none", np.random.default_rng(5))
    pick = np.random.default_rng(5)
    s, k = pick.integers(6, size=400), pick.integers(3, size=400)
    truth_placed = canonical_points(runs.points[s, k].astype(np.float32), runs.truths[s])
    angles = np.array([
        rotation_error_deg(_best_rotation(t, h), np.eye(3)) for t, h in zip(truth_placed, x)
    ])  # fmt: skip
    assert 0.3 < labels.mean() < 0.5  # 40% a few degrees off; the rest turned away
    assert angles[labels == 1].max() < 10.5
    assert angles[(labels == 0) & (weights == 1)].min() > 25
    assert np.isclose(weights[labels == 1].min(), 1.0)


def test_upright_knocked_off_truths_keep_the_truths_up_and_turn_about_it(rng):
    """For runs held upright, every synthetic hypothesis takes the truth's up onto the canonical
    up within the 3 degrees of tilt it is given; the wrong ones are turned about up."""
    runs = _runs(rng)
    config = VerifierConfig(pose_model=Path("x.onnx"), batch=400, synthetic=1.0)
    x, labels, weights = hypothesis_batch(runs, config, "none", np.random.default_rng(5), True)
    pick = np.random.default_rng(5)
    s, k = pick.integers(6, size=400), pick.integers(3, size=400)
    truth_placed = canonical_points(runs.points[s, k].astype(np.float32), runs.truths[s])
    turns = np.array([_best_rotation(t, h) for t, h in zip(truth_placed, x)])
    tilt = np.degrees(np.arccos(np.clip(turns[:, 1, 1], -1.0, 1.0)))
    assert tilt.max() < 3.5
    angles = rotation_error_deg(turns, np.eye(3))
    assert angles[labels == 1].max() < 15.5  # the labels agree with the turns the points show
    assert angles[(labels == 0) & (weights == 1)].min() > 25
    assert 0.3 < labels.mean() < 0.5


def test_runs_of_a_model_that_requires_up_are_held_upright(make_net, tmp_path, rng):
    """The verifier's training runs of an upright model start stood up on the scan's sensed up
    and stay upright: each run's pose takes that up onto +y (within the 2 degrees it is off)."""
    from itnet.export.onnx_export import export_step
    from itnet.model.data import ScanSet
    from itnet.model.verifier import pose_runs
    from itnet.model_card import ModelCard

    card = ModelCard(name="m", category="monitor", points=128, requires_up=True)
    export_step(make_net(), card, tmp_path / "m.onnx")
    model = load_model(tmp_path / "m.onnx", warm_up=False)
    truths = np.tile(np.eye(4), (3, 1, 1))
    truths[:, :3, :3] = random_rotation(rng, 3)
    clouds = [rng.normal(size=(300, 3)) * [1.0, 0.5, 0.2] for _ in range(3)]
    scans = ScanSet(clouds, truths, np.ones(3), ["a", "b", "c"])
    runs = pose_runs(model, scans, 4, 64, seed=1, up_error_deg=2.0)
    assert runs.poses.shape == (3, 4, 4, 4)
    true_up = truths[:, 1, :3]  # R^T e_y: the canonical up in each scan's frame
    lifted = np.einsum("skij,sj->ski", runs.poses[..., :3, :3].astype(np.float64), true_up)
    assert np.degrees(np.arccos(np.clip(lifted[..., 1], -1, 1))).max() < 2.5
    free = pose_runs(model, scans, 4, 64, seed=1)
    lifted = np.einsum("skij,sj->ski", free.poses[..., :3, :3].astype(np.float64), true_up)
    assert np.degrees(np.arccos(np.clip(lifted[..., 1], -1, 1))).max() > 10


@pytest.fixture(scope="module")
def trained(tmp_path_factory, make_net):  # type: ignore[no-untyped-def]
    """A tiny pose model of bathtubs, its verifier trained 30 steps by the command on clean views
    and views by a Kinect v2, exported."""
    from modelnet_tree import write_modelnet_tree
    from test_centre_fit_cli import _tub

    from itnet.export.onnx_export import export_step
    from itnet.model_card import ModelCard

    root = tmp_path_factory.mktemp("verifier")
    data = write_modelnet_tree(
        root / "data", {"bathtub": _tub}, np.random.default_rng(0), train=12, test=1
    )
    models = root / "models"
    card = ModelCard(name="tub", category="bathtub", symmetry="yaw180", points=256,
                     recommended_iterations=2, verify_fused=True)  # fmt: skip
    export_step(make_net(), card, models / "tub.onnx")
    args = ["verifier-train", "--pose-model", str(models / "tub.onnx"), "--out",
            str(root / "run"), "--steps", "30", "--batch", "16", "--views", "1", "--scanners",
            "paper,paper+kinect_v2", "--ensemble", "2", "--data", str(data), "--cache", str(root / "cache")]  # fmt: skip
    done = runner.invoke(app, args)
    assert done.exit_code == 0, done.output
    exported = runner.invoke(app, ["verifier-export", str(root / "run" / "verifier.pt"),
                                   "--out", str(models / "tub-verifier.onnx")])  # fmt: skip
    assert exported.exit_code == 0, exported.output
    return root, models


def test_the_command_trains_on_the_runs_and_the_export_scores_as_the_network(trained):
    from itnet.model.verifier import load_verifier

    root, models = trained
    rows = [json.loads(line) for line in (root / "run" / "log.jsonl").read_text().splitlines()]
    assert rows[-1]["step"] == 30 and np.isfinite(rows[-1]["loss"])
    assert list((root / "cache").glob("verifier-runs-*-bathtub-paper-1-2-*.npz"))
    assert list((root / "cache").glob("verifier-runs-*-bathtub-paper+kinect_v2-1-2-*.npz"))
    loaded = load_any(models / "tub-verifier.onnx", warm_up=True)
    assert isinstance(loaded, LoadedVerifier) and loaded.score_ms > 0
    assert loaded.card.category == "bathtub" and loaded.card.trained_on == "tub.onnx"
    net, config = load_verifier(root / "run" / "verifier.pt")
    assert config.ensemble == 2 and config.scanners == ["paper", "paper+kinect_v2"]
    x = np.random.default_rng(0).normal(size=(5, 100, 3)).astype(np.float32)
    with torch.no_grad():
        expected = net(torch.from_numpy(x))[:, 0].numpy()
    assert np.allclose(loaded.scores(x), expected, atol=1e-4)
    refused = runner.invoke(app, ["card", str(models / "tub-verifier.onnx"), "--verify-fused"])
    assert refused.exit_code == 2 and "verifier-export" in refused.stderr


def test_an_unknown_view_rule_or_camera_is_refused_before_any_run(tmp_path):
    for scanners, said in (("paper,sideways", "unknown view rule 'sideways'"),
                           ("paper+kinect_9", "unknown sensor 'kinect_9'")):  # fmt: skip
        refused = runner.invoke(app, ["verifier-train", "--pose-model",
                                      str(SHIPPED / "chair.onnx"), "--out", str(tmp_path / "run"),
                                      "--scanners", scanners])  # fmt: skip
        assert refused.exit_code == 2 and said in refused.stderr
        assert not (tmp_path / "run").exists()


def test_verify_anchors_on_the_likeliest_run_without_the_probes(trained, monkeypatch):
    _, models = trained
    loaded, _ = load_all(models, warm_up=False)
    model = loaded["tub"]
    assert model.verifier is not None and model.verifier.card.name == "bathtub-verifier"

    def no_probes(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise AssertionError("the probes ran although a verifier is loaded")

    monkeypatch.setattr("itnet.pose.stages.basin_drift", no_probes)
    cloud = np.random.default_rng(2).normal(size=(600, 3)) * [1.0, 0.45, 0.35]
    run = run_with(model, cloud, budget_ms=5000, max_iterations=2, ensemble=3)
    assert "verify" in run.plan.stage_names  # the card's verify_fused
    run.run_to_end()
    assert run.result()["verified"] is True
    scores = model.verifier.scores(canonical_points(run.points, run.pose_normalized))
    anchored = fuse_poses(run.pose_normalized, "yaw180", anchor=likeliest_run(scores))
    expected = pose_from_normalized(anchored, run.normalization)
    assert np.allclose(run.result()["T_canonical_from_input"], expected, atol=1e-5)
    # runs held upright are weighed by the learned verifier too (the probes would tilt them)
    upright = run_with(model, cloud, budget_ms=5000, max_iterations=2, ensemble=3, up=[0, 1, 0])
    assert "verify" in upright.plan.stage_names
    upright.run_to_end()
    assert upright.result()["verified"] is True and upright.result()["up"] == [0.0, 1.0, 0.0]
    tight = run_with(model, cloud, budget_ms=5000, max_iterations=2, ensemble=3)
    model.verifier.score_ms = 1e9  # a call the budget cannot hold: the fusion stays as it is
    tight.run_to_end()
    assert tight.result()["verified"] is False


def test_the_service_lists_the_verifier_and_refuses_two_of_a_category(trained, tmp_path):
    from fastapi.testclient import TestClient

    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    _, models = trained
    with TestClient(create_app(Settings(model_dir=models, warm_up=False))) as client:
        (info,) = client.get("/v1/models").json()["models"]
        assert info["name"] == "tub" and info["verifier"] == "bathtub-verifier"
    twice = tmp_path / "twice"
    shutil.copytree(models, twice)
    shutil.copy(twice / "tub-verifier.onnx", twice / "another-verifier.onnx")
    with pytest.raises(ModelLoadError, match="two verifiers of bathtub"):
        load_all(twice, warm_up=False)
    alone = load_model(models / "tub.onnx", warm_up=False)  # one file: no verifier beside it
    assert alone.verifier is None


class _FakeVerifier:
    """Scores a single run ``single`` and a recheck's runs ``runs``; predicts ``ms`` a call."""

    def __init__(self, single: float, runs: list[float], ms: float = 0.0) -> None:
        self.card = type("Card", (), {"name": "fake", "category": "bathtub", "points": 256})()
        self.single, self.runs, self.ms = single, np.array(runs, np.float32), ms

    def scores(self, points: np.ndarray) -> np.ndarray:
        return np.array([self.single], np.float32) if len(points) == 1 else self.runs

    def predicted_ms(self, runs: int, points: int) -> float:
        return self.ms


@pytest.fixture
def tub(trained):  # type: ignore[no-untyped-def]
    return load_model(trained[1] / "tub.onnx", warm_up=False)


def test_a_doubted_single_run_is_rechecked_and_the_likeliest_anchors(tub):
    cloud = np.random.default_rng(4).normal(size=(500, 3)) * [1.0, 0.45, 0.35]
    kw = {"budget_ms": 5000, "max_iterations": 3, "seed": 7}
    tub.verifier = _FakeVerifier(-1.0, [-3.0, 2.0, -3.0, -3.0])
    run = run_with(tub, cloud, recheck=True, **kw)
    run.run_to_end()
    reply = run.result()
    assert reply["rechecked"] is True and reply["iterations"] == 3
    # the recheck's runs are an ensemble's: the same subsets (seed + 1), starts and steps
    tub.verifier = None
    runs = run_with(tub, cloud, ensemble=4, **{**kw, "seed": 8})
    runs.run_to_end()
    plain = run_with(tub, cloud, **kw)
    plain.run_to_end()
    everyone = np.concatenate([plain.pose_normalized[:1], runs.pose_normalized])
    expected = pose_from_normalized(fuse_poses(everyone, "yaw180", anchor=2), plain.normalization)
    assert np.allclose(reply["T_canonical_from_input"], expected, atol=1e-5)
    assert not np.allclose(
        reply["T_canonical_from_input"], plain.result()["T_canonical_from_input"]
    )


@pytest.mark.parametrize(
    ("fake", "rechecked"),
    [(_FakeVerifier(0.5, []), None), (_FakeVerifier(-1.0, [1, 1, 1, 1], ms=1e9), None)],
    ids=["not doubted", "no time"],
)
def test_a_trusted_run_or_a_tight_budget_keeps_the_single_run(tub, fake, rechecked):
    cloud = np.random.default_rng(4).normal(size=(500, 3)) * [1.0, 0.45, 0.35]
    kw = {"budget_ms": 5000, "max_iterations": 3, "seed": 7}
    plain = run_with(tub, cloud, **kw)
    plain.run_to_end()
    tub.verifier = fake
    run = run_with(tub, cloud, recheck=True, **kw)
    run.run_to_end()
    # not doubted: no word of it; no time for the verifier: the stage is skipped, and said
    assert "rechecked" not in run.result()
    assert run.result()["skipped"] == ([] if fake.single > 0 else ["recheck"])
    assert np.allclose(run.result()["T_canonical_from_input"],
                       plain.result()["T_canonical_from_input"])  # fmt: skip


def test_recheck_is_refused_without_a_verifier_or_beside_an_ensemble_and_follows_the_card(tub):
    from itnet.pose.errors import BadCloudError

    cloud = np.random.default_rng(4).normal(size=(500, 3))
    tub.verifier = None
    with pytest.raises(BadCloudError, match="no verifier"):
        run_with(tub, cloud, recheck=True)
    tub.verifier = _FakeVerifier(-1.0, [0.0] * 4)
    with pytest.raises(BadCloudError, match="single run"):
        run_with(tub, cloud, recheck=True, ensemble=2)
    with pytest.raises(BadCloudError, match="single run"):
        run_with(tub, cloud, recheck=True, up=[0.0, 1.0, 0.0])
    assert "recheck" not in run_with(tub, cloud).plan.stage_names  # the card's recheck_runs is 0
    tub.card = tub.card.model_copy(update={"recheck_runs": 2})
    by_card = run_with(tub, cloud)
    assert ("recheck" in by_card.plan.stage_names) and by_card.model.card.recheck_runs == 2
    assert (
        "recheck" not in run_with(tub, cloud, ensemble=2).plan.stage_names
    )  # fused runs: verify's job


def test_http_and_the_card_command_recheck(trained, tmp_path):
    from fastapi.testclient import TestClient

    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    _, models = trained
    one = {"accuracy": 60.0, "gain": 0.0, "gain_stderr": 0.0, "scans": 40}
    off = {"machine": "test", "budget_ms": 50.0, "split": "val", "paper": {"1": one}}
    on = {**off, "paper": {"1": {**one, "accuracy": 64.0, "rechecked": 0.2,
                                 "versus_baseline": {"gain": 4.0, "gain_stderr": 1.5}}}}  # fmt: skip
    (tmp_path / "off.json").write_text(json.dumps(off))
    (tmp_path / "on.json").write_text(json.dumps(on))
    served = tmp_path / "served"
    shutil.copytree(models, served)
    card = ["card", str(served / "tub.onnx"), "--recheck-runs", "4"]
    bare = runner.invoke(app, card)
    assert bare.exit_code == 2 and "--with-recheck" in bare.output
    done = runner.invoke(app, [*card, "--without-recheck", str(tmp_path / "off.json"),
                               "--with-recheck", str(tmp_path / "on.json")])  # fmt: skip
    assert done.exit_code == 0, done.output
    with TestClient(create_app(Settings(model_dir=served, warm_up=False))) as client:
        (info,) = client.get("/v1/models").json()["models"]
        assert info["recheck_runs"] == 4
        assert (
            "paper 60.0% -> 64.0% (+4.0 ± 1.5, 40 scans, 20% rechecked)"
            in (info["recheck_evaluation"])
        )
        cloud = np.random.default_rng(4).normal(size=(500, 3)).tolist()
        body = {"points": cloud, "model": "tub", "budget_ms": 5000, "max_iterations": 2}
        reply = client.post("/v1/estimate", json=body)
        assert reply.status_code == 200, reply.text
        # the tiny verifier doubts the run or not; where it does, the recheck had the time
        assert reply.json().get("rechecked", True) is True
        refused = client.post("/v1/estimate", json={**body, "recheck": True, "ensemble": 2})
        assert refused.status_code == 422 and "single run" in refused.text
        from itnet.clients import ItnetClient, ItnetRequestError

        http = ItnetClient("http://testserver")
        http._http = client  # the app in-process: TestClient is an httpx.Client
        kw = {"model": "tub", "budget_ms": 5000, "max_iterations": 2}
        for binary in (False, True):  # the field reaches the service in both bodies
            with pytest.raises(ItnetRequestError, match="single run"):
                http.estimate(cloud, recheck=True, ensemble=2, binary=binary, **kw)
            assert http.estimate(cloud, recheck=False, binary=binary, **kw).rechecked is None


def test_the_pose_command_rechecks_or_refuses(trained, tmp_path):
    _, models = trained
    path = tmp_path / "cloud.npy"
    np.save(path, np.random.default_rng(4).normal(size=(500, 3)).astype(np.float32))
    args = ["pose", str(path), "--model", "tub", "--model-dir", str(models), "--json",
            "--max-iterations", "2", "--budget-ms", "5000"]  # fmt: skip
    done = runner.invoke(app, [*args, "--recheck"])
    assert done.exit_code == 0, done.output
    row = json.loads(done.output.strip().splitlines()[-1])
    assert row.get("rechecked", True) is True  # where the tiny verifier doubts it: in time
    refused = runner.invoke(app, [*args, "--recheck", "--ensemble", "2"])
    assert refused.exit_code != 0 and "single run" in refused.output
