"""The classifier's build steps from Python: ``train_classifier`` trains the run a
``ClassifyTrainConfig`` asks for, ``export_classifier_run`` exports it and reports what it wrote
and measured, as ``classify-train`` and ``classify-export`` print it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from itnet.export.classifier_build_config import ClassifierExportConfig
from itnet.model.classify.configs import ClassifyTrainConfig


@pytest.mark.train
def test_a_run_trained_and_exported_from_python_reports_its_card(
    three_classes: Path, tmp_path: Path
) -> None:
    from itnet.export.classifier_build import export_classifier_run
    from itnet.model.classify.train_run import train_classifier
    from itnet.model.input_error import InputError
    from itnet.pose.runtime import LoadedClassifier, load_any

    config = ClassifyTrainConfig(
        variant="none", data=three_classes, out=tmp_path / "run", cache=tmp_path / "cache",
        steps=4, batch=8, eval_every=4, compile=False, views="occluded",
    )  # fmt: skip
    trained = train_classifier(config, log_progress=False)
    result = json.loads((config.out / "result.json").read_text())
    assert trained.variant == "none" and trained.result == result
    assert trained.validation_accuracy == result["val"]["accuracy"] and trained.test is not None
    assert json.loads((config.out / "config.json").read_text())["views"] == ["occluded"]
    out = tmp_path / "models" / "classifier.onnx"
    asked = ClassifierExportConfig(out=out, points=32, report=tmp_path / "export.json",
                                   weights_out=tmp_path / "shipped.pt")  # fmt: skip
    report = export_classifier_run(config.out, asked)
    graph = load_any(out, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card == report.card
    assert report.card.points == 32 and report.card.transformer == "none"
    assert report.size_bytes == out.stat().st_size and report.max_difference < 1e-4
    assert report.torch_test == trained.test["accuracy"]
    assert report.weights_out == tmp_path / "shipped.pt" and report.weights_bytes > 0
    assert report.confusion is None and report.unsure is not None
    written = json.loads((tmp_path / "export.json").read_text())["unsure"]
    assert written["test_views"] == report.unsure["test_views"] == 3 * 2 * 4
    assert written["threshold"] == report.unsure["threshold"] == report.card.threshold
    import torch

    bad = tmp_path / "bad.pt"
    torch.save({"model": {}}, bad)
    with pytest.raises(InputError, match="not a classifier checkpoint"):
        export_classifier_run(bad, asked)
