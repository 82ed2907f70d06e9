"""``itnet centre-fit``: poses training scans as served, fits the correction, measures it on the
validation views, and writes it into the card; a model posing nothing right gets a clear error."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.cli import app
from itnet.pose.runtime import load_model

runner = CliRunner()


def _tub(rng: np.random.Generator, n: int = 300) -> np.ndarray:
    """A noisy open-top box, long along x, z up (ModelNet's frame)."""
    size = np.array([1.0, 0.45, 0.35]) * rng.uniform(0.9, 1.1, size=3)
    face = rng.integers(5, size=n)
    points = rng.uniform(-1, 1, size=(n, 3))
    points[np.arange(n), np.array([0, 0, 1, 1, 2])[face]] = np.array([-1, 1, -1, 1, -1])[face]
    return points * size + rng.normal(0, 0.005, size=(n, 3))


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory, export_model):  # type: ignore[no-untyped-def]
    from modelnet_tree import write_modelnet_tree

    from itnet.model_card import ModelCard

    root = tmp_path_factory.mktemp("centre_fit")
    data = write_modelnet_tree(
        root / "data", {"bathtub": _tub}, np.random.default_rng(0), train=20, test=2
    )
    card = ModelCard(name="bathtub", category="bathtub", symmetry="yaw180", points=256,
                     recommended_iterations=2)  # fmt: skip
    export_model(card, root / "bathtub.onnx")
    return root, data


def _fit(root: Path, data: Path, *extra: str):  # type: ignore[no-untyped-def]
    args = ["centre-fit", str(root / "bathtub.onnx"), "--data", str(data), "--views", "1",
            "--val-views", "2", "--cache", str(root / "cache"), *extra]  # fmt: skip
    return runner.invoke(app, args)


def test_the_correction_is_fitted_measured_and_written(setup) -> None:  # type: ignore[no-untyped-def]
    root, data = setup
    out, report = root / "fitted.onnx", root / "report.json"
    # the tiny untrained network's rotations are anything: fit on all of them
    done = _fit(root, data, "--max-rotation", "181", "--write", "--out", str(out),
                "--report", str(report), "--ensemble", "2")  # fmt: skip
    assert done.exit_code == 0, done.output
    measured = json.loads(report.read_text())
    assert set(measured["results"]) == {"occluded", "paper"}
    assert measured["results"]["paper"]["scans"] > 0
    fitted = load_model(out, threads=1)
    assert fitted.centre is not None
    assert fitted.card.centre_evaluation == measured["evaluation"]
    assert fitted.card.centre_evaluation.startswith("validation views, 2 runs fused")
    assert fitted.centre_viewpoint is not None and fitted.centre_viewpoint.uses_viewpoint
    assert load_model(root / "bathtub.onnx", threads=1).centre is None  # --out: left as it was


def test_a_model_that_poses_nothing_right_is_refused(setup) -> None:  # type: ignore[no-untyped-def]
    root, data = setup
    done = _fit(root, data, "--max-rotation", "0.001")
    assert done.exit_code == 2
    assert "not accurate enough to fit a centre correction" in done.output


def test_up_fits_the_correction_held_upright_into_its_own_field(setup) -> None:  # type: ignore[no-untyped-def]
    """--up: the runs are held upright by each scan's (tilted) up, as the service holds a
    request that gives up; the correction goes into centre_correction_up and its viewpoint
    variant into centre_correction_up_viewpoint, leaving the card's other corrections as they
    were, and both are measured beside the card's corrections on the same upright runs."""
    root, data = setup
    plain, out, report = root / "plain.onnx", root / "upright.onnx", root / "up.json"
    assert _fit(root, data, "--max-rotation", "181", "--write", "--out", str(plain)).exit_code == 0
    args = ["centre-fit", str(plain), "--data", str(data), "--views", "1", "--val-views", "2",
            "--cache", str(root / "cache"), "--max-rotation", "181", "--write", "--out", str(out),
            "--report", str(report), "--up", "2"]  # fmt: skip
    done = runner.invoke(app, args)
    assert done.exit_code == 0, done.output
    measured = json.loads(report.read_text())
    assert measured["up_error_deg"] == 2.0
    assert set(measured["viewpoint_results"]) == {"occluded", "paper"}
    assert set(measured["served_viewpoint_results"]) == {"occluded", "paper"}
    assert "held upright by an up 2 deg off" in measured["evaluation"]
    # the card's plain correction, measured on the same upright runs: what up requests had
    assert set(measured["plain_results"]) == {"occluded", "paper"}
    assert "the plain correction (fitted on runs not held)" in measured["evaluation"]
    fitted, before = load_model(out, threads=1), load_model(plain, threads=1)
    assert fitted.centre_up is not None and not fitted.centre_up.uses_viewpoint
    assert fitted.centre_up_viewpoint is not None and fitted.centre_up_viewpoint.uses_viewpoint
    assert fitted.card.centre_up_evaluation == measured["evaluation"]
    assert "the viewpoint correction fitted held upright" in measured["evaluation"]
    # the others are left as they were
    assert fitted.card.centre_correction == before.card.centre_correction is not None
    assert fitted.card.centre_correction_viewpoint == before.card.centre_correction_viewpoint
    assert fitted.card.centre_evaluation == before.card.centre_evaluation != ""
    # the upright runs differ from the unheld ones: another fit
    assert fitted.card.centre_correction_up != before.card.centre_correction


def test_kinds_names_the_views_fitted_and_measured_a_camera_included(setup) -> None:  # type: ignore[no-untyped-def]
    """--kinds: the view rules the correction is fitted on and measured on, a camera's views
    (real-sized pieces through its sensor model) among them; an unknown rule or camera is one
    line and exit 2."""
    root, data = setup
    report = root / "kinds.json"
    done = _fit(root, data, "--max-rotation", "181", "--kinds", "occluded,paper+kinect_v2",
                "--report", str(report))  # fmt: skip
    assert done.exit_code == 0, done.output
    measured = json.loads(report.read_text())
    assert set(measured["results"]) == {"occluded", "paper+kinect_v2"}
    assert measured["results"]["paper+kinect_v2"]["scans"] > 0
    assert "paper+kinect_v2" in measured["evaluation"]
    for wrong, says in (("occluded,lidar", "unknown view rule 'lidar'"),
                        ("occluded+lidar", "unknown sensor 'lidar'")):  # fmt: skip
        refused = _fit(root, data, "--kinds", wrong)
        assert refused.exit_code == 2 and says in refused.output, refused.output


def test_no_keep_viewpoint_writes_the_correction_alone(setup) -> None:  # type: ignore[no-untyped-def]
    """--no-keep-viewpoint: the viewpoint variant is measured (and its line in the card's
    evaluation says it was not kept) but the card's own viewpoint correction stays as it was."""
    root, data = setup
    plain, upright, again = root / "plain_vp.onnx", root / "up_only.onnx", root / "again.onnx"
    assert _fit(root, data, "--max-rotation", "181", "--write", "--out", str(plain)).exit_code == 0
    done = _fit(root, data, "--max-rotation", "181", "--write", "--out", str(upright), "--up", "2",
                "--no-keep-viewpoint")  # fmt: skip
    assert done.exit_code == 0, done.output
    fitted = load_model(upright, threads=1)
    assert fitted.centre_up is not None and fitted.centre_up_viewpoint is None
    assert "the viewpoint correction fitted held upright (measured, not kept)" in (
        fitted.card.centre_up_evaluation
    )
    # without up: the plain correction is refitted (other scans), the viewpoint one left as it is
    args = ["centre-fit", str(plain), "--data", str(data), "--views", "1", "--val-views", "2",
            "--cache", str(root / "cache"), "--max-rotation", "181", "--write", "--out",
            str(again), "--no-keep-viewpoint", "--seed", "7"]  # fmt: skip
    assert runner.invoke(app, args).exit_code == 0
    before, after = load_model(plain, threads=1), load_model(again, threads=1)
    assert after.card.centre_correction_viewpoint == before.card.centre_correction_viewpoint
    assert before.card.centre_correction_viewpoint is not None
    assert after.card.centre_correction != before.card.centre_correction
    assert "(measured, not kept)" in after.card.centre_evaluation


def test_out_must_name_an_onnx_file(setup) -> None:  # type: ignore[no-untyped-def]
    """A --out that is no .onnx path is refused before anything is posed, naming the option."""
    root, data = setup
    done = _fit(root, data, "--write", "--out", str(root / "fit.json"))
    assert done.exit_code == 2
    assert "--out" in done.output and ".onnx" in done.output
    assert not (root / "fit.json").exists()
