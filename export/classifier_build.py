"""A trained classifier run -> its served ONNX graph, checked and measured
(``export_classifier_run``):

1. the run's best classifier (and ``fuse_with``'s heads behind its canonicaliser) exported to
   one graph (``classifier_export.export_classifier``), the heads cascaded (``cascade``) or
   the per-point layers quantised to int8 where asked;
2. the graph checked against torch on a random cloud (the largest difference of the
   probabilities);
3. the graph itself measured on the run's validation and test views (an upright graph fused
   with ``beside``, as it is served): its card carries that test accuracy and the unsure
   threshold chosen on validation;
4. beside it, where asked: the run's weights without optimiser state, a JSON report (the
   card, the graph's test metrics, the threshold's effect) and the confusion matrix's plot.

    report = export_classifier_run(Path("runs/cls/itnet-2"), ClassifierExportConfig())
    report.card.accuracy, report.max_difference             # 0.912, 3e-07

A shipped checkpoint (``weights_out`` of an earlier export) exports as its run: the run is
remade from the config it keeps (``train.run_of_checkpoint``).
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch

from itnet.export.cascade import cascade_graph, cascade_probabilities
from itnet.export.classifier_build_config import ClassifierExportConfig
from itnet.export.classifier_export import (
    GraphScores,
    card_from_run,
    export_classifier,
    fused_probabilities,
    heads_name,
    score_graph,
    trained_points,
    unsure_split,
)
from itnet.export.onnx_export import save_with_card
from itnet.export.quantize import quantize_point_layers
from itnet.model.classify.network import Classifier
from itnet.model.classify.train import load_classifier, metrics, run_of_checkpoint
from itnet.model.input_error import InputError
from itnet.model_card import ClassifierCard
from itnet.pose.runtime import LoadedClassifier, load_any


@dataclass(frozen=True)
class ClassifierExportReport:
    """What an export wrote and measured: the graph (``out``, its size in bytes) and its card;
    torch's validation and test accuracy of the run (test None: held back); the largest
    |graph - torch| probability on a random cloud; and the files written beside it where asked
    (the shipped weights and their size, the JSON report with the threshold's effect on the
    test views, the confusion plot)."""

    out: Path
    size_bytes: int
    card: ClassifierCard
    torch_validation: float
    torch_test: float | None
    max_difference: float
    weights_out: Path | None = None
    weights_bytes: int = 0
    report: Path | None = None
    unsure: dict[str, float] | None = None
    confusion: Path | None = None


def export_classifier_run(run: Path, config: ClassifierExportConfig) -> ClassifierExportReport:
    """Export ``run`` (a finished run folder, or a shipped checkpoint whose run is remade) as
    ``config`` asks. Raises InputError for a checkpoint that is not a classifier's, heads that
    do not share the run's transformer, or a ``beside`` that is not a classifier for any
    orientation."""
    with tempfile.TemporaryDirectory() as made:  # a run remade from a checkpoint
        if run.is_file():
            try:
                run = run_of_checkpoint(run, Path(made) / "run")
            except ValueError as err:
                raise InputError(str(err)) from None
        return _export_run(run, config)


def _export_run(run: Path, config: ClassifierExportConfig) -> ClassifierExportReport:
    """``export_classifier_run`` of a run folder."""
    nets = [load_classifier(path)[0] for path in (run / "best.pt", *config.fuse_with)]
    provisional = provisional_card(run, nets, config)
    graph = write_graph(nets, provisional, config)
    difference = torch_difference(graph, nets, provisional, config.cascade)
    partner = serving_partner(graph, config.beside)
    scores = score_graph(graph, run, partner)
    card = measured_card(run, scores, graph, provisional, config, partner)
    save_with_card(onnx.load(str(config.out)), card, config.out)
    result = json.loads((run / "result.json").read_text())
    test = result["test"]  # None: a run trained with --hold-test
    report = ClassifierExportReport(
        out=config.out,
        size_bytes=config.out.stat().st_size,
        card=card,
        torch_validation=float(result["val"]["accuracy"]),
        torch_test=None if test is None else float(test["accuracy"]),
        max_difference=difference,
    )
    return write_beside(run, scores, report, config)


def provisional_card(
    run: Path, nets: list[Classifier], config: ClassifierExportConfig
) -> ClassifierCard:
    """The card the graph is exported with, before it is measured: the run's classes, variant
    and upright flag, the points served, the canonicaliser's points (default: as trained),
    the heads and the cascade."""
    result = json.loads((run / "result.json").read_text())
    upright = json.loads((run / "config.json").read_text()).get("upright") is not None
    canonical = config.canonical_points
    return ClassifierCard(
        classes=result["classes"],
        points=config.points or trained_points(run),
        transformer=result["variant"],
        upright=upright,
        canonical_points=nets[0].config.canonical_points if canonical is None else canonical,
        head=heads_name(nets),
        cascade=config.cascade,
    )


def write_graph(
    nets: list[Classifier], card: ClassifierCard, config: ClassifierExportConfig
) -> LoadedClassifier:
    """Write ``config.out``: the nets as one graph (cascaded or int8 where asked) with
    ``card``. Returns the graph loaded as the service loads it."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            graph = export_classifier(nets[0], card, Path(tmp) / "float32.onnx", fused=nets[1:])
        except ValueError as err:
            raise InputError(str(err)) from None
        if config.cascade is not None:
            onnx.save(cascade_graph(onnx.load(str(graph)), config.cascade), str(graph))
        if config.int8:
            quantize_point_layers(graph, config.out)
        else:
            config.out.parent.mkdir(parents=True, exist_ok=True)
            config.out.write_bytes(graph.read_bytes())
    loaded = load_any(config.out, warm_up=False)
    assert isinstance(loaded, LoadedClassifier)
    return loaded


def torch_difference(
    graph: LoadedClassifier, nets: list[Classifier], card: ClassifierCard, cascade: float | None
) -> float:
    """The largest |graph - torch| probability on a random cloud of as many points as the
    canonicaliser sees (then torch's pose is the graph's); torch's answer is the cascade's
    where the graph cascades."""
    seen = min(card.points, card.canonical_points or card.points)
    x = np.random.default_rng(0).normal(size=(1, seen, 3)).astype(np.float32)
    cloud = torch.from_numpy(x)
    with torch.no_grad():
        expected = (
            fused_probabilities(nets, cloud)
            if cascade is None
            else cascade_probabilities(nets, cloud, cascade)
        ).numpy()
    return float(np.abs(graph.probabilities(x) - expected).max())


def serving_partner(graph: LoadedClassifier, beside: Path) -> LoadedClassifier | None:
    """The classifier for any orientation an upright graph is served fused with (``beside``);
    None for a graph that is not upright. Raises InputError where ``beside`` is not one."""
    if not graph.card.upright:
        return None
    partner = load_any(beside, warm_up=False)
    if not isinstance(partner, LoadedClassifier) or partner.card.upright:
        raise InputError(f"--beside {beside} is not a classifier for any orientation")
    return partner


def measured_card(
    run: Path,
    scores: GraphScores,
    graph: LoadedClassifier,
    provisional: ClassifierCard,
    config: ClassifierExportConfig,
    partner: LoadedClassifier | None,
) -> ClassifierCard:
    """The graph's card: its accuracy and threshold measured on ``scores``
    (``card_from_run``), its precision, canonicaliser's points, heads and cascade as
    exported, and the fused checkpoints' names in its training."""
    beside = None if partner is None else config.beside.name
    measured = card_from_run(run, scores, config.points, config.target, beside)
    fused = {"fused_with": [p.name for p in config.fuse_with]} if config.fuse_with else {}
    return measured.model_copy(
        update={
            "precision": graph.card.precision,
            "canonical_points": provisional.canonical_points,
            "head": provisional.head,
            "cascade": provisional.cascade,
            "training": {**measured.training, **fused},
        }
    )


def write_beside(
    run: Path, scores: GraphScores, report: ClassifierExportReport, config: ClassifierExportConfig
) -> ClassifierExportReport:
    """Write what ``config`` asks for beside the graph (the shipped weights, the JSON report,
    the confusion plot) -> ``report`` with them."""
    done: dict[str, Any] = {}
    if config.weights_out is not None:
        from itnet.model.train import ship_checkpoint

        ship_checkpoint(run / "best.pt", config.weights_out)
        done.update(weights_out=config.weights_out, weights_bytes=config.weights_out.stat().st_size)
    card = report.card
    graph_test = {
        "classes": card.classes,
        "test": metrics(scores.test_probs, scores.test_labels, card.classes),
    }
    if config.report is not None:
        split = unsure_split(scores, card.threshold)
        written = {"card": card.model_dump(), "unsure": split, "test": graph_test["test"]}
        config.report.write_text(json.dumps(written, indent=1))
        done.update(report=config.report, unsure=split)
    if config.confusion is not None:
        from itnet.model.classify.report import plot_confusion

        name = f"{config.out.name} ({card.transformer}, {card.head})"
        done.update(confusion=plot_confusion(graph_test, config.confusion, name))
    return replace(report, **done)
