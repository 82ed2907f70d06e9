"""Export one IT-Net step, ``(points, pose) -> (pose_next, delta)``, to a single ONNX file.

The whole step is in the graph — move the input by the pose, regress the update, compose — so the
runtime never re-implements quaternion math. Batch and point count are dynamic. BatchNorm is
folded by the exporter.
"""

from __future__ import annotations

from pathlib import Path

import onnx
import torch

from itnet.model.network import ExportableStep, ITNet
from itnet.model_card import METADATA_KEY, ClassifierCard, ModelCard, VerifierCard

INPUT_NAMES = ["points", "pose"]
OUTPUT_NAMES = ["pose_next", "delta"]


def export_step(net: ITNet, card: ModelCard, path: Path, opset: int = 20) -> Path:
    """Write ``path`` (.onnx): the step graph with ``card`` as metadata. Returns the path."""
    step = ExportableStep(net.eval()).eval()
    points = torch.randn(2, 64, 3)
    pose = torch.eye(4).expand(2, 4, 4).contiguous()
    batch, count = torch.export.Dim("batch", min=1, max=4096), torch.export.Dim("points", min=1)
    program = torch.onnx.export(
        step,
        (points, pose),
        dynamo=True,
        opset_version=opset,
        input_names=INPUT_NAMES,
        output_names=OUTPUT_NAMES,
        dynamic_shapes={"points": {0: batch, 1: count}, "pose": {0: batch}},
        external_data=False,
        verbose=False,
    )
    return save_with_card(program.model_proto, card, path)


def save_with_card(
    model: onnx.ModelProto, card: ModelCard | ClassifierCard | VerifierCard, path: Path
) -> Path:
    """Write ``model`` to ``path`` as one file with ``card`` as its only itnet metadata, and
    check it. Returns the path."""
    for i in reversed(range(len(model.metadata_props))):
        if model.metadata_props[i].key == METADATA_KEY:
            del model.metadata_props[i]
    entry = model.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, card.model_dump_json()
    model.producer_name = "itnet"
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, str(path))
    onnx.checker.check_model(str(path))
    return path
