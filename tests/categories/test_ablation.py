"""The ablation table's driver, on tiny synthetic chairs (seconds)."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.cli import app


@pytest.mark.train
def test_ablation_rows_train_measure_and_write_the_table(tmp_path):
    rng = np.random.default_rng(0)
    for split, count in (("train", 12), ("test", 3)):
        folder = tmp_path / "data" / "chair" / split
        folder.mkdir(parents=True)
        for i in range(count):  # chair-like, in ModelNet's frame (+z up, back on +y)
            seat = rng.uniform([-0.5, -0.5, -0.05], [0.5, 0.5, 0.05], size=(150, 3))
            back = rng.uniform([-0.5, 0.4, 0.05], [0.5, 0.5, 0.9], size=(150, 3))
            np.save(folder / f"chair_{i:02d}.npy", np.concatenate([seat, back]))
    ran = CliRunner().invoke(app, [
        "fit", "ablation", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
        "--cache", str(tmp_path / "cache"), "--steps", "2", "--batch", "4", "--views", "1",
        "--threads", "1", "--rows", "K=1,no stop (K=5)",
    ])  # fmt: skip
    assert ran.exit_code == 0, ran.output
    results = json.loads((tmp_path / "out" / "ablation.json").read_text())
    assert [r["row"] for r in results] == ["K=1", "no stop (K=5)"]
    assert all(0 <= r["at_10"] <= 100 and r["scans"] == 3 for r in results)
    assert "| K=1 |" in ran.stdout  # the table, printed
    text = (tmp_path / "out" / "ablation.md").read_text()
    assert "| K=1 |" in text and "36.9" in text and "| no stop (K=5) |" in text and "4.1" in text
    # each row is its own resumable run, trained to the step count
    assert (tmp_path / "out" / "K1" / "last.pt").exists()
    assert (tmp_path / "out" / "no_stop" / "last.pt").exists()
