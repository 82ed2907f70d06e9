"""A trained checkpoint -> one served ONNX step with its model card, checked against torch.

The card is the checkpoint's training (category, points, iterations, schedule) with what
``ExportOptions`` add: the name, the category for a network of several, the runtime's defaults,
the mirror planes and the measurements. The written graph is run beside the torch network on
random clouds; the largest difference is reported.

    done = export_checkpoint(Path("runs/chair/best.pt"), ExportOptions(out=Path("c.onnx")))
    done.path, done.max_diff                    # c.onnx, 3e-06
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from itnet.export.card_measurements import anytime_evaluation, ensemble_evaluation, mirror_planes
from itnet.export.export_config import ExportOptions
from itnet.export.onnx_export import export_step
from itnet.export.quantize import quantize_point_layers
from itnet.model.categories import model_category
from itnet.model.input_error import InputError
from itnet.model.network import ITNet
from itnet.model.train import load_checkpoint
from itnet.model_card import ModelCard
from itnet.pose.runtime import load_model

MODELS = Path("itnet/models")
"""Where a model goes without ``ExportOptions.out``: the package's models, as <name>.onnx."""


@dataclass(frozen=True)
class ExportReport:
    """The written model: its file, size, card, and the largest absolute difference of its
    step from the torch network's on random clouds."""

    path: Path
    size_bytes: int
    card: ModelCard
    max_diff: float


def export_checkpoint(checkpoint: Path, options: ExportOptions) -> ExportReport:
    """Export ``checkpoint`` as ``options`` say and check the graph against torch. Raises
    InputError where the category, the mirror planes or a measurement is refused."""
    net, state = load_checkpoint(checkpoint)
    card = checkpoint_card(state, options)
    out = options.out or MODELS / f"{card.name}.onnx"
    if options.int8:
        with tempfile.TemporaryDirectory() as tmp:
            quantize_point_layers(export_step(net, card, Path(tmp) / "float32.onnx"), out)
    else:
        export_step(net, card, out)
    return ExportReport(out, out.stat().st_size, card, onnx_difference(net, out, card.points))


def checkpoint_card(state: dict[str, Any], options: ExportOptions) -> ModelCard:
    """The card of a checkpoint (``load_checkpoint``'s dict) exported with ``options``."""
    config = state["config"]
    trained_on = str(config["category"])
    try:
        cat = model_category(options.category, trained_on, config.get("symmetry"))
    except ValueError as err:
        raise InputError(str(err)) from None
    accuracy, evaluation = {}, ""
    if options.report is not None:
        accuracy, evaluation = anytime_evaluation(options.report)
    ensemble_text = ensemble_evaluation(options.recommended_ensemble, options.ensemble_report)
    upright = config.get("upright")
    return ModelCard(
        name=options.name or cat.name,  # a mug model is served as 'mug', not 'chair'
        category=cat.name,
        symmetry=cat.symmetry,
        mirror_planes=mirror_planes(options.mirror_planes, cat.mirror_planes),
        version=options.version,
        points=int(config["points"]) if options.points is None else options.points,
        trained_points=config["points"],
        trained_iterations=config["iterations"],
        recommended_iterations=options.recommended_iterations,
        recommended_ensemble=options.recommended_ensemble,
        accuracy=accuracy,
        evaluation=evaluation,
        ensemble_evaluation=ensemble_text,
        # an upright network knows only levelled views: served to requests that give up
        requires_up=upright is not None,
        training={
            "steps": state["step"],
            "batch": config["batch"],
            "lr": config["lr"],
            "decay_every": config["decay_every"],
            "bf16": config["bf16"],
            "validation": state["metrics"].get("val_accuracy"),
            "categories": trained_on,
            **({"upright": upright} if upright is not None else {}),
        },
    )


def onnx_difference(net: ITNet, path: Path, points: int, clouds: int = 4) -> float:
    """The largest absolute difference of the next pose between the graph at ``path`` and
    ``net``, from the identity, on ``clouds`` random clouds (seeded) of ``points`` points."""
    model = load_model(path, warm_up=False)
    x = np.random.default_rng(0).normal(size=(clouds, points, 3)).astype(np.float32)
    pose = np.tile(np.eye(4, dtype=np.float32), (clouds, 1, 1))
    with torch.no_grad():
        expected = net.step(torch.from_numpy(x), torch.from_numpy(pose))[0].numpy()
    return float(np.abs(model.step(x, pose)[0] - expected).max())
