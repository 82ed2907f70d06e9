"""``itnet card``: a model's card changed without its weights, with the mirror's measurement."""

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.cli import app
from itnet.model_card import describe_mirror
from itnet.pose.runtime import load_model

runner = CliRunner()


def bench_report(accuracy: float, finished: float | None = None) -> dict:
    row = {"accuracy": accuracy, "gain": 0.0, "gain_stderr": 0.0, "scans": 40}
    if finished is not None:
        row["mirror_finished"] = finished
    return {"machine": "test", "budget_ms": 20.0, "split": "test", "paper": {"1": row}}


def test_card_sets_the_planes_and_their_measurement_and_keeps_the_weights(tiny_model_dir, tmp_path):
    path = tmp_path / "tiny.onnx"
    shutil.copy(tiny_model_dir / "tiny.onnx", path)
    before = load_model(path, warm_up=False)
    (tmp_path / "without.json").write_text(json.dumps(bench_report(70.0)))
    (tmp_path / "with.json").write_text(json.dumps(bench_report(75.0, 0.95)))
    args = ["card", str(path), "--mirror-planes", "x,z", "--without-mirror",
            str(tmp_path / "without.json"), "--with-mirror", str(tmp_path / "with.json")]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    after = load_model(path, warm_up=False)
    assert after.card.mirror_planes == ["x", "z"]
    assert after.card.mirror_evaluation == json.loads(result.stdout)["mirror_evaluation"]
    assert "paper 70.0% -> 75.0% (40 scans, 95% finished in time)" in after.card.mirror_evaluation
    assert (
        after.card.model_copy(update={"mirror_planes": [], "mirror_evaluation": ""}) == before.card
    )
    x = np.random.default_rng(0).normal(size=(2, 256, 3)).astype(np.float32)
    pose = np.tile(np.eye(4, dtype=np.float32), (2, 1, 1))
    assert np.array_equal(before.step(x, pose)[0], after.step(x, pose)[0])  # the same weights
    shown = runner.invoke(app, ["card", str(path)])  # no options: only shows it
    assert json.loads(shown.stdout)["mirror_planes"] == ["x", "z"]


def test_card_refuses_bad_planes_half_a_measurement_and_the_classifier(tiny_model_dir, tmp_path):
    path = tmp_path / "tiny.onnx"
    shutil.copy(tiny_model_dir / "tiny.onnx", path)
    wrong = runner.invoke(app, ["card", str(path), "--mirror-planes", "y"])
    assert wrong.exit_code == 2 and "--mirror-planes" in wrong.output
    (tmp_path / "with.json").write_text(json.dumps(bench_report(75.0)))
    half = runner.invoke(app, ["card", str(path), "--with-mirror", str(tmp_path / "with.json")])
    assert half.exit_code == 2 and "neither" in half.output
    assert load_model(path, warm_up=False).card.mirror_planes == []  # nothing was written
    from pathlib import Path

    classifier = Path(__file__).parents[1] / "itnet" / "models" / "classifier.onnx"
    refused = runner.invoke(app, ["card", str(classifier), "--mirror-planes", "x"])
    assert refused.exit_code == 2 and "classifier" in refused.stderr


def test_card_sets_mirror_fused_only_with_planes(tiny_model_dir, tmp_path):
    path = tmp_path / "tiny.onnx"
    shutil.copy(tiny_model_dir / "tiny.onnx", path)
    refused = runner.invoke(app, ["card", str(path), "--mirror-fused"])  # no planes yet
    assert refused.exit_code == 2 and "planes" in refused.output
    done = runner.invoke(app, ["card", str(path), "--mirror-planes", "x", "--mirror-fused"])
    assert done.exit_code == 0, done.output
    assert load_model(path, warm_up=False).card.mirror_fused is True
    cleared = runner.invoke(app, ["card", str(path), "--mirror-planes", "none"])
    assert cleared.exit_code == 0, cleared.output  # no planes: nothing left to finish by
    card = load_model(path, warm_up=False).card
    assert card.mirror_planes == [] and card.mirror_fused is False


def tiny_and_its_ensemble_report(tiny_model_dir, tmp_path):
    """A copy of the tiny model, and a bench_ensemble JSON of 8 runs against one (paper views,
    66.0% against 60.0%) beside it as ens.json."""
    path = tmp_path / "tiny.onnx"
    shutil.copy(tiny_model_dir / "tiny.onnx", path)
    report = bench_report(60.0)
    report["paper"]["8"] = {"accuracy": 66.0, "gain": 6.0, "gain_stderr": 2.0, "scans": 40}
    (tmp_path / "ens.json").write_text(json.dumps(report))
    return path


def test_card_sets_the_recommended_ensemble_with_its_measurement(tiny_model_dir, tmp_path):
    path = tiny_and_its_ensemble_report(tiny_model_dir, tmp_path)
    bare = runner.invoke(app, ["card", str(path), "--recommended-ensemble", "8"])
    assert bare.exit_code == 2 and "--ensemble-report" in bare.output
    wrong = runner.invoke(app, ["card", str(path), "--recommended-ensemble", "4",
                                "--ensemble-report", str(tmp_path / "ens.json")])  # fmt: skip
    assert wrong.exit_code == 2 and "4 runs" in wrong.output  # the report has no K = 4
    done = runner.invoke(app, ["card", str(path), "--recommended-ensemble", "8",
                               "--ensemble-report", str(tmp_path / "ens.json")])  # fmt: skip
    assert done.exit_code == 0, done.output
    card = load_model(path, warm_up=False).card
    assert card.recommended_ensemble == 8
    assert card.ensemble_evaluation.startswith("8 runs fused, within 20 ms, on the test views")
    assert "paper 66.0% (one run 60.0%, +6.0 ± 2.0; 40 scans)" in card.ensemble_evaluation
    back = runner.invoke(app, ["card", str(path), "--recommended-ensemble", "1"])
    assert back.exit_code == 0, back.output
    card = load_model(path, warm_up=False).card
    assert card.recommended_ensemble == 1 and card.ensemble_evaluation == ""


def test_describe_mirror_needs_the_same_scans():
    other = bench_report(75.0)
    other["paper"]["1"]["scans"] = 41
    with pytest.raises(ValueError, match="different scans"):
        describe_mirror(bench_report(70.0), other)


def test_card_requires_up_only_with_its_measurement(tiny_model_dir, tmp_path):
    path = tmp_path / "tiny.onnx"
    shutil.copy(tiny_model_dir / "tiny.onnx", path)
    unmeasured = runner.invoke(app, ["card", str(path), "--requires-up"])
    assert unmeasured.exit_code == 2 and "--up-report" in unmeasured.output
    without_up = bench_report(60.0)
    (tmp_path / "plain.json").write_text(json.dumps(without_up))
    refused = runner.invoke(app, ["card", str(path), "--requires-up", "--up-report",
                                  str(tmp_path / "plain.json")])  # fmt: skip
    assert refused.exit_code == 2 and "without --up" in refused.output
    assert load_model(path, warm_up=False).card.requires_up is False  # nothing was written
    up = {**bench_report(81.5), "up_error_deg": 2.0}
    up["paper"]["1"]["stderr"] = 1.9
    (tmp_path / "up.json").write_text(json.dumps(up))
    result = runner.invoke(app, ["card", str(path), "--requires-up", "--up-report",
                                 str(tmp_path / "up.json")])  # fmt: skip
    assert result.exit_code == 0, result.output
    card = load_model(path, warm_up=False).card
    assert card.requires_up is True
    assert card.up_evaluation.startswith("one run, the up direction given (tilted 2 deg")
    assert "paper 81.5% ± 1.9 (40 scans)" in card.up_evaluation


def test_card_records_an_eval_report_as_its_accuracy_per_iteration(tiny_model_dir, tmp_path):
    """`itnet card --report` writes an `itnet eval` report's curve into an installed model's
    card, as `itnet export --report` does; a report measured with up says so."""
    path = tmp_path / "tiny.onnx"
    shutil.copy(tiny_model_dir / "tiny.onnx", path)
    rep = {"iterations": [0, 1, 2], "accuracy": [0.0, 0.25, 0.5], "scans": 40, "views": 5,
           "scanner": "occluded", "category": "chair", "points": 256, "up_error_deg": 2.0}  # fmt: skip
    (tmp_path / "report.json").write_text(json.dumps(rep))
    result = runner.invoke(app, ["card", str(path), "--report", str(tmp_path / "report.json")])
    assert result.exit_code == 0, result.output
    card = load_model(path, warm_up=False).card
    assert card.accuracy == {"0": 0.0, "1": 0.25, "2": 0.5}
    assert card.evaluation.startswith("40 partial scans (5 random occluded views")
    assert "the up direction given (2 deg off the truth), held upright" in card.evaluation


def test_card_adds_views_by_a_depth_camera_to_the_served_measurement(tiny_model_dir, tmp_path):
    path = tiny_and_its_ensemble_report(tiny_model_dir, tmp_path)
    no_card = runner.invoke(app, ["card", str(path), "--camera-report", str(tmp_path / "ens.json")])
    assert no_card.exit_code == 2 and "no ensemble_evaluation" in no_card.output
    runner.invoke(app, ["card", str(path), "--recommended-ensemble", "8",
                        "--ensemble-report", str(tmp_path / "ens.json")])  # fmt: skip
    camera = {"machine": "test", "budget_ms": 20.0, "split": "test",
              "occluded+kinect_v2": {"1": {"accuracy": 40.0, "gain": 0.0, "gain_stderr": 0.0,
                                           "scans": 30},
                                     "8": {"accuracy": 48.0, "gain": 8.0, "gain_stderr": 2.5,
                                           "scans": 30}}}  # fmt: skip
    (tmp_path / "camera.json").write_text(json.dumps(camera))
    clean = runner.invoke(app, ["card", str(path), "--camera-report", str(tmp_path / "ens.json")])
    assert clean.exit_code == 2 and "RULE+SENSOR" in clean.output
    done = runner.invoke(app, ["card", str(path), "--camera-report", str(tmp_path / "camera.json")])
    assert done.exit_code == 0, done.output
    card = load_model(path, warm_up=False).card
    assert "occluded+kinect_v2 48.0% (one run 40.0%, +8.0 ± 2.5; 30 scans)" in (
        card.ensemble_evaluation
    )
    assert "paper 66.0%" in card.ensemble_evaluation  # the clean views kept
    camera["budget_ms"] = 50.0
    (tmp_path / "other.json").write_text(json.dumps(camera))
    other = runner.invoke(app, ["card", str(path), "--camera-report", str(tmp_path / "other.json")])
    assert other.exit_code == 2 and "within 50 ms" in other.output
