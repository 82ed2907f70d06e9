"""The table report from finished rows: markdown between its markers, JSON, confusion plot."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from itnet.model.classify.report import write_report
from itnet.model.classify.train import metrics

CLASSES = ["bed", "chair", "table"]


def _row(out: Path, variant: str, correct: float, rng: np.random.Generator) -> None:
    labels = rng.integers(0, 3, 300)
    probs = rng.dirichlet(np.ones(3), 300)
    right = rng.random(300) < correct
    probs[right, labels[right]] += 2.0  # those views win their own class
    result = {"variant": variant, "classes": CLASSES, "best_step": 200, "steps": 300,
              "val": metrics(probs[:100], labels[:100], CLASSES),
              "test": metrics(probs, labels, CLASSES)}  # fmt: skip
    (out / variant).mkdir(parents=True)
    (out / variant / "result.json").write_text(json.dumps(result))


def test_report_writes_the_table_and_keeps_the_rest_of_the_page(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    out, docs = tmp_path / "runs", tmp_path / "docs"
    _row(out, "none", 0.5, rng)
    _row(out, "itnet-2", 0.9, rng)
    docs.mkdir()
    (docs / "classification.md").write_text("intro\n\n<!-- table --><!-- /table -->\n\noutro\n")
    write_report(out, docs)
    page = (docs / "classification.md").read_text()
    assert page.startswith("intro") and page.rstrip().endswith("outro")
    assert "| none |" in page and "| IT-Net, 2 iterations |" in page and "69.94" in page
    assert "Trained on: " in page and "`itnet classify-experiment`, 300 steps a row" in page
    summary = json.loads((docs / "classification.json").read_text())
    assert summary["best_by_validation"] == "itnet-2"
    assert (docs / "confusion_table.png").stat().st_size > 10_000
    assert not (docs / "confusion.png").exists()  # the shipped graph's: classify-export's
    write_report(out, docs)  # a rerun replaces the table instead of adding a second one
    assert (docs / "classification.md").read_text().count("<!-- table") == 1


def test_a_rerun_without_the_rows_runs_keeps_the_recorded_table(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    out, docs = tmp_path / "runs", tmp_path / "docs"
    _row(out, "none", 0.5, rng)
    _row(out, "itnet-2", 0.7, rng)
    write_report(out, docs, trained="one GPU, batch 100")
    table = (docs / "classification.md").read_text()
    assert "Trained on: one GPU, batch 100." in table
    (docs / "confusion.png").write_bytes(b"the shipped graph's plot")
    write_report(tmp_path / "gone", docs)
    assert (docs / "classification.md").read_text() == table  # the recorded rows stay, and where
    summary = json.loads((docs / "classification.json").read_text())
    assert (
        set(summary["rows"]) == {"none", "itnet-2"} and summary["best_by_validation"] == "itnet-2"
    )
    assert (docs / "confusion.png").read_bytes() == b"the shipped graph's plot"
