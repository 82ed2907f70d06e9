"""Tiny classifiers for the tests: random ones, and ones whose answer is fixed by their last
layer (zero weights, chosen biases)."""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

CLASSES = ["chair", "table", "sofa"]
TINY = {"point_channels": (8, 16, 32), "head_channels": (16, 8)}
# the exported name of the last layer's bias (``Classifier.classifier.out.bias``)
FIXED_BIAS = "heads.0.dense_b.2"


def tiny_classifier(transformer: str = "itnet", iterations: int = 1, classes: int = 3, **kw: Any):  # type: ignore[no-untyped-def]
    from itnet.model.classify.network import Classifier, ClassifierConfig

    config = ClassifierConfig(
        classes=classes, transformer=transformer, iterations=iterations, **TINY, **kw
    )
    return Classifier(config)


def randomised(net: Any, seed: int) -> Any:
    """Random weights (the transformer's last layer included: not the identity) and random
    BatchNorm statistics, eval mode."""
    import torch

    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.Linear):
                m.weight.copy_(torch.randn(m.weight.shape, generator=gen) * 0.3)
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.copy_(torch.randn(m.num_features, generator=gen) * 0.2)
                m.running_var.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
                m.weight.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
                m.bias.copy_(torch.randn(m.num_features, generator=gen) * 0.2)
    return net.eval()


def fixed_answer_classifier(logits: list[float]):  # type: ignore[no-untyped-def]
    """A classifier whose probabilities are softmax(logits) whatever the cloud."""
    import torch

    net = tiny_classifier(classes=len(logits))
    with torch.no_grad():
        net.classifier.out.weight.zero_()
        net.classifier.out.bias.copy_(torch.tensor(logits))
    return net.eval()


@functools.cache
def _fixed_graph(classes: int) -> bytes:
    """The ONNX graph of ``fixed_answer_classifier`` with ``classes`` outputs and zero logits,
    exported once: every fixed answer is this graph with its last bias set."""
    from itnet.export.classifier_export import export_classifier
    from itnet.model_card import ClassifierCard

    card = ClassifierCard(classes=[f"c{k}" for k in range(classes)], points=128, accuracy=0.9)
    with tempfile.TemporaryDirectory() as tmp:
        path = export_classifier(
            fixed_answer_classifier([0.0] * classes), card, Path(tmp) / "c.onnx"
        )
        return path.read_bytes()


def export_fixed(
    folder: Path,
    logits: list[float],
    threshold: float = 0.5,
    size_prior: Any = None,
    upright: bool = False,
    classes: list[str] | None = None,
    points: int = 128,
) -> Path:
    """classifier.onnx (``upright``: classifier_upright.onnx, its card upright) in ``folder``:
    softmax(``logits``) over ``classes`` (default ``CLASSES``) whatever the cloud."""
    import onnx
    from onnx import numpy_helper

    from itnet.export.onnx_export import save_with_card
    from itnet.model_card import ClassifierCard

    card = ClassifierCard(classes=classes or CLASSES, points=points, threshold=threshold,
                          accuracy=0.9, size_prior=size_prior, upright=upright)  # fmt: skip
    graph = onnx.load_model_from_string(_fixed_graph(len(card.classes)))
    (bias,) = [i for i in graph.graph.initializer if i.name == FIXED_BIAS]
    bias.CopyFrom(numpy_helper.from_array(np.asarray(logits, np.float32), FIXED_BIAS))
    name = "classifier_upright.onnx" if upright else "classifier.onnx"
    return save_with_card(graph, card, folder / name)


# synthetic classes in the ModelNet layout: a flat plate, a long rod, a ball
SHAPES = {
    "plate": lambda r, n: r.uniform(-1, 1, (n, 3)) * [1.0, 0.05, 0.7],
    "rod": lambda r, n: r.uniform(-1, 1, (n, 3)) * [0.08, 1.0, 0.08],
    "ball": lambda r, n: (lambda v: v / np.linalg.norm(v, axis=1, keepdims=True))(
        r.normal(size=(n, 3))
    ),
}


def tiny_run(data: Path, out: Path, **overrides: object):  # type: ignore[no-untyped-def]
    """A tiny itnet-1 run on ``data`` into ``out``/run (cache in ``out``/cache)."""
    from itnet.model.classify.train import ClassifyConfig

    base = {
        "data": data, "variant": "itnet-1", "out": out / "run", "cache": out / "cache",
        "steps": 60, "batch": 16, "points": 64, "lr": 3e-3, "decay_every": 1000,
        "eval_every": 30, "log_every": 10, "val_views": 2, "test_views": 2,
        "widths": ((16, 32, 64), (32, 16)), "bf16": False,
    }  # fmt: skip
    return ClassifyConfig.model_validate({**base, **overrides})
