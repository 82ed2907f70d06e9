"""Dynamic int8 quantisation of an exported step graph (onnxruntime.quantization).

Only the per-point layers that carry the work are quantised: 64->128 and 128->1,024, the
matrix products whose constant operand is ``point_w1`` / ``point_w2`` of
``ExportableStep``; 128->1,024 is 94% of the step's 287 MFLOP at 1,024 points. The first layer
(the raw coordinates) and the head (one vector per cloud) stay float32. Activations are quantised
per call (uint8, scale from their range), weights once (int8, per tensor).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import onnx

from itnet.export.onnx_export import save_with_card
from itnet.model_card import METADATA_KEY, ModelCard

QUANTISED_WEIGHTS = ("point_w1", "point_w2")


def quantize_step(source: Path, target: Path, name: str | None = None) -> Path:
    """Write ``target``: ``source`` with its big per-point matrix products in int8, and its model
    card marked ``precision='int8'`` (renamed to ``name`` if given). Returns ``target``."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    model = onnx.load(str(source))
    nodes = [
        n.name
        for n in model.graph.node
        if n.op_type == "MatMul" and any(i in QUANTISED_WEIGHTS for i in n.input)
    ]
    if len(nodes) != len(QUANTISED_WEIGHTS):
        raise ValueError(f"{source}: expected matrix products with {QUANTISED_WEIGHTS}")
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


def _card(model: onnx.ModelProto) -> ModelCard:
    for entry in model.metadata_props:
        if entry.key == METADATA_KEY:
            return ModelCard.model_validate_json(entry.value)
    raise ValueError("not an itnet model (no model card)")
