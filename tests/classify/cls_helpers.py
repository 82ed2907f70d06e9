"""Tiny classifiers for the tests: random ones, and ones whose answer is fixed by their last
layer (zero weights, chosen biases)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

CLASSES = ["chair", "table", "sofa"]
TINY = {"point_channels": (8, 16, 32), "head_channels": (16, 8)}


def tiny_classifier(transformer: str = "itnet", iterations: int = 1, classes: int = 3, **kw: Any):  # type: ignore[no-untyped-def]
    from itnet.model.classify.network import Classifier, ClassifierConfig

    config = ClassifierConfig(
        classes=classes, transformer=transformer, iterations=iterations, **TINY, **kw
    )
    return Classifier(config)


def fixed_answer_classifier(logits: list[float]):  # type: ignore[no-untyped-def]
    """A classifier whose probabilities are softmax(logits) whatever the cloud."""
    import torch

    net = tiny_classifier()
    with torch.no_grad():
        net.classifier.out.weight.zero_()
        net.classifier.out.bias.copy_(torch.tensor(logits))
    return net.eval()


def export_fixed(
    folder: Path,
    logits: list[float],
    threshold: float = 0.5,
    size_prior: Any = None,
    upright: bool = False,
) -> Path:
    """classifier.onnx (``upright``: classifier_upright.onnx, its card upright) in ``folder``."""
    from itnet.export.classifier_export import export_classifier
    from itnet.model_card import ClassifierCard

    card = ClassifierCard(classes=CLASSES, points=128, threshold=threshold, accuracy=0.9,
                          size_prior=size_prior, upright=upright)  # fmt: skip
    name = "classifier_upright.onnx" if upright else "classifier.onnx"
    return export_classifier(fixed_answer_classifier(logits), card, folder / name)
