"""Dynamic int8 quantisation of an exported graph's per-point layers (onnxruntime.quantization).

Every PointNet in an itnet graph (the pose step; the classifier's unrolled canonicaliser steps
and its own PointNet) spends its time in the per-point matrix products after the first layer:
64->128 and 128->1,024, whose constant operand is a ``point_w1``/``point_w2`` (pose step,
``step.point_w1``...) or ``point_w.1``/``point_w.2`` (a folded PointNet) initializer. 128->1,024
alone is 94% of a step's 287 MFLOP at 1,024 points. The first layer (the raw coordinates) and
the heads (one vector per cloud) stay float32. Activations are quantised per call (uint8, scale
from their range), weights once (int8, per tensor).
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import onnx

from itnet.export.onnx_export import save_with_card
from itnet.model_card import METADATA_KEY, ClassifierCard, ModelCard, parse_card

# a per-point layer's weight other than the first: point_w1, step.point_w2, classifier.point_w.1
POINT_LAYER = re.compile(r"(^|\.)point_w\.?([1-9][0-9]*)$")


def point_layer_nodes(model: onnx.ModelProto) -> list[str]:
    """Names of the MatMul nodes whose constant operand is a per-point weight (first layer
    excluded), in graph order; an unrolled step's weights are used by several nodes."""
    weights = {i.name for i in model.graph.initializer if POINT_LAYER.search(i.name)}
    return [
        n.name
        for n in model.graph.node
        if n.op_type == "MatMul" and any(i in weights for i in n.input)
    ]


def quantize_point_layers(source: Path, target: Path, name: str | None = None) -> Path:
    """Write ``target``: ``source`` (a pose step or a classifier) with its per-point matrix
    products after the first in int8, and its card marked ``precision='int8'`` (renamed to
    ``name`` if given). Returns ``target``. Raises ValueError for a graph without such layers
    or without an itnet card."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    model = onnx.load(str(source))
    nodes = point_layer_nodes(model)
    if not nodes:
        raise ValueError(f"{source}: no per-point matrix products (point_w1, point_w.1, ...)")
    card = _card(model).model_copy(update={"precision": "int8", **({"name": name} if name else {})})
    with tempfile.TemporaryDirectory() as tmp:
        quantised = Path(tmp) / "int8.onnx"
        quantize_dynamic(
            str(source),
            str(quantised),
            weight_type=QuantType.QInt8,
            nodes_to_quantize=nodes,
            # the weights are the left operand (channels-first layout), which the quantiser
            # skips by default
            extra_options={"MatMulConstBOnly": False},
        )
        result = onnx.load(str(quantised))
    return save_with_card(result, card, target)


def _card(model: onnx.ModelProto) -> ModelCard | ClassifierCard:
    for entry in model.metadata_props:
        if entry.key == METADATA_KEY:
            return parse_card(entry.value)
    raise ValueError("not an itnet model (no model card)")
