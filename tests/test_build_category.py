"""``itnet build CATEGORY``: a category's model from its data to the files that ship, resumable."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.cli import app

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "modelnet10" / "chair"


def _few_chairs(root: Path, train: int = 16, test: int = 4) -> Path:
    """A ModelNet-style root with a few of the real chairs (train/ and test/)."""
    for split, count in (("train", train), ("test", test)):
        folder = root / "chair" / split
        folder.mkdir(parents=True)
        for path in sorted((SHARED / split).iterdir())[:count]:
            shutil.copy(path, folder / path.name)
    return root


@pytest.mark.train
@pytest.mark.skipif(not SHARED.is_dir(), reason="ModelNet10 is not beside the repository")
def test_a_build_ships_a_compact_model_with_its_verifier_and_measured_card(tmp_path):
    data, out = _few_chairs(tmp_path / "data"), tmp_path / "build"
    args = ["build", "chair", "--data", str(data), "--out", str(out), "--steps", "2",
            "--batch", "4", "--eval-every", "2", "--no-compile", "--views", "1", "--runs", "2",
            "--verifier-steps", "2", "--verifier-views", "1", "--centre-views", "2", "--cache", str(tmp_path / "cache"),
            "--budget-ms", "200"]  # fmt: skip
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    model, verifier = (Path(line) for line in first.stdout.split())
    assert model == out / "model" / "chair.onnx" and verifier.name == "chair-verifier.onnx"

    from itnet.pose.runtime import load_any, load_model

    card = load_model(model, warm_up=False).card
    assert card.recommended_ensemble == 2 and not card.requires_up
    assert card.centre_correction is not None  # the centre stage wrote its correction
    served = card.measurement("ensemble")
    assert served is not None and served.split == "test" and served.budget_ms == 200
    assert {r.views for r in served.results} == {"occluded", "surface", "paper"}
    assert all(r.runs == 2 and r.scans == 4 for r in served.results)
    assert json.loads((out / "served.json").read_text())["paper"]["2"]["scans"] == 4
    assert load_any(verifier, warm_up=False).card.kind == "verifier"
    compacted = json.loads((out / "compact.json").read_text())["bytes_saved"]
    assert compacted["chair.onnx"] > 0 and compacted["chair-verifier.onnx"] > 0
    cloud = np.random.default_rng(0).normal(size=(300, 3))
    assert load_model(model).step(cloud[None, :256].astype(np.float32),
                                  np.eye(4, dtype=np.float32)[None])[0].shape == (1, 4, 4)  # fmt: skip

    again = CliRunner().invoke(app, args)  # everything done: nothing runs again
    assert again.exit_code == 0, again.output
    assert all(line.endswith(")") and ": done (" in line for line in again.stderr.splitlines())


def test_a_build_refuses_a_category_it_does_not_know(tmp_path):
    result = CliRunner().invoke(app, ["build", "lamp", "--out", str(tmp_path / "b")])
    assert result.exit_code == 2 and "unknown category 'lamp'" in result.output
    assert not (tmp_path / "b").exists()
