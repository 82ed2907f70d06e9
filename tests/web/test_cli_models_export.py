"""``itnet models`` (the CLI twin of GET /v1/models) and ``itnet export``'s model name."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from itnet.cli import app
from itnet.model_listing import runs_cell
from itnet.pose.runtime import load_model
from itnet.service.app import create_app
from itnet.service.settings import Settings

runner = CliRunner()
SHIPPED = Path(__file__).resolve().parents[2] / "itnet" / "models"
WEIGHTS = Path(__file__).resolve().parents[2] / "lab" / "weights"  # torch weights, not shipped


def test_models_lists_what_the_service_lists(tiny_model_dir):
    listed = runner.invoke(app, ["models", "--model-dir", str(tiny_model_dir), "--json"])
    assert listed.exit_code == 0, listed.output
    with TestClient(create_app(Settings(model_dir=tiny_model_dir))) as client:
        served = client.get("/v1/models").json()
    cli = json.loads(listed.stdout)
    assert cli["default_model"] == served["default_model"] == "tiny"

    def without_timing(entries: list[dict]) -> list[dict]:
        return [{k: v for k, v in e.items() if k != "step_ms"} for e in entries]

    assert without_timing(cli["models"]) == without_timing(served["models"])
    assert cli["models"][0]["step_ms"] > 0


def centre_column(card) -> str:  # type: ignore[no-untyped-def]
    """What `itnet models` shows for a card's centre corrections."""
    kinds = [
        kind
        for kind, field in (("yes", card.centre_correction),
                            ("vp", card.centre_correction_viewpoint),
                            ("up", card.centre_correction_up),
                            ("upvp", card.centre_correction_up_viewpoint))
        if field
    ]  # fmt: skip
    return "+".join(kinds) or "-"


def test_models_table_shows_the_shipped_cards():
    table = runner.invoke(app, ["models"])
    assert table.exit_code == 0, table.output
    header, *rows = table.stdout.splitlines()
    assert header.split() == ["name", "category", "symmetry", "mirror", "centre", "up",
                              "precision", "points", "runs", "verifier", "accuracy",
                              "step"]  # fmt: skip
    for name in ("chair", "bed"):  # the bed's card recommends 8 runs fused
        row = next(r for r in rows if r.startswith(f"{name} "))
        card = load_model(SHIPPED / f"{name}.onnx", warm_up=False).card
        accuracy = 100 * card.accuracy[str(card.recommended_iterations)]
        assert card.mirror_planes == ["x"]  # left-right symmetric; front and back differ
        centre = centre_column(card)
        assert row.split()[:8] == [name, card.category, card.symmetry, "x", centre, "-",
                                   card.precision, str(card.points)]  # fmt: skip
        runs = runs_cell(card.recommended_ensemble, card.coarse_steps, card.halving)
        assert f" {runs} " in row and runs.startswith(str(card.recommended_ensemble))
        assert f"{accuracy:.1f}% at {card.recommended_iterations} it." in row
        assert ("default" in row) == (name == "chair")
        # their learned verifiers: verify for fused runs, and the chair's recheck for one run
        assert card.verify_fused
        assert (" verify+recheck:4 " if name == "chair" else " verify ") in row
    # the night stand is served only with the up direction: its row says so
    night = next(r for r in rows if r.startswith("night_stand "))
    assert night.split()[5] == "needed"
    assert load_model(SHIPPED / "night_stand.onnx", warm_up=False).card.requires_up
    # the dresser too, its centre finished by the correction fitted held upright
    dresser = load_model(SHIPPED / "dresser.onnx", warm_up=False)
    row = next(r for r in rows if r.startswith("dresser "))
    assert row.split()[:8] == ["dresser", "dresser", "yaw180", "x,z", "up+upvp", "needed", "int8",
                               "256"]  # fmt: skip
    # one run by default, its first 9 steps on 64 points; its verifier anchors only the runs a
    # request asks to fuse
    assert " 1, 9x64 pts " in row and dresser.card.coarse_steps == (9, 64)
    assert dresser.card.verify_fused and row.split()[11] == "verify-if-fused"
    assert dresser.card.requires_up and dresser.centre_up is not None and dresser.centre is None
    assert "held upright" in dresser.card.centre_up_evaluation
    bed = load_model(SHIPPED / "bed.onnx", warm_up=False).card
    assert bed.recommended_ensemble == 8 and "8 runs fused, within 50 ms" in bed.ensemble_evaluation
    assert (
        bed.mirror_fused
        and not load_model(SHIPPED / "bathtub.onnx", warm_up=False).card.mirror_fused
    )
    # the bathtub: 8 runs fused within the default 50 ms, every step (no schedule); two mirror
    # planes
    row = next(r for r in rows if r.startswith("bathtub "))
    tub = load_model(SHIPPED / "bathtub.onnx", warm_up=False).card
    assert row.split()[:9] == ["bathtub", "bathtub", "yaw180", "x,z",
                               centre_column(tub), "-", "int8", "256", "8"]  # fmt: skip
    assert "8 runs fused, within 50 ms" in tub.ensemble_evaluation
    # the sofa: 8 runs fused, finished by its left-right mirror too
    row = next(r for r in rows if r.startswith("sofa "))
    sofa = load_model(SHIPPED / "sofa.onnx", warm_up=False).card
    assert row.split()[:9] == ["sofa", "sofa", "none", "x",
                               centre_column(sofa), "-", "int8", "256", "8,"]  # fmt: skip
    assert sofa.mirror_fused and "8 runs fused, within 50 ms" in sofa.ensemble_evaluation


def test_models_in_a_folder_without_models_is_an_error(tmp_path):
    result = runner.invoke(app, ["models", "--model-dir", str(tmp_path)])
    assert result.exit_code == 2 and "no .onnx models" in result.stderr


@pytest.mark.slow
def test_export_names_the_model_after_its_category(tmp_path):
    """A model trained with --category mug is served as 'mug' (it used to be 'chair')."""
    torch = pytest.importorskip("torch")
    state = torch.load(WEIGHTS / "chair.pt", map_location="cpu", weights_only=False)
    state["config"] = {**state["config"], "category": "mug"}
    checkpoint = tmp_path / "mug.pt"
    torch.save(state, checkpoint)
    out = tmp_path / "models" / "mug.onnx"
    out.parent.mkdir()
    result = runner.invoke(app, ["export", str(checkpoint), "--out", str(out)])
    assert result.exit_code == 0, result.output
    card = load_model(out, warm_up=False).card
    assert (card.name, card.category) == ("mug", "mug")


@pytest.mark.parametrize("name", ["chair", "toilet", "sofa", "dresser", "desk", "monitor"])
def test_shipped_weights_are_the_shipped_model(name):
    """lab/weights/NAME.pt (the weights to fine-tune from) computes the step that NAME.onnx
    serves, up to the int8 rounding of its point layers: a few degrees on clouds of noise, while another model's weights are
    over 150 degrees off (median)."""
    torch = pytest.importorskip("torch")
    from itnet.geometry import rotation_error_deg
    from itnet.model.train import load_checkpoint

    net, _ = load_checkpoint(WEIGHTS / f"{name}.pt")
    served = load_model(SHIPPED / f"{name}.onnx", warm_up=False)
    x = np.random.default_rng(0).normal(size=(8, 256, 3)).astype(np.float32)
    pose = np.tile(np.eye(4, dtype=np.float32), (8, 1, 1))
    with torch.no_grad():
        want = net.step(torch.from_numpy(x), torch.from_numpy(pose))[0].numpy()
    got = served.step(x, pose)[0]
    errors = rotation_error_deg(got[:, :3, :3], want[:, :3, :3])
    assert np.median(errors) < 3.0 and errors.max() < 10.0, errors
    assert np.abs(got[:, :3, 3] - want[:, :3, 3]).max() < 0.05
