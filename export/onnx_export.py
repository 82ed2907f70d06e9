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
from itnet.model_card import METADATA_KEY, ModelCard

INPUT_NAMES = ["points", "pose"]
OUTPUT_NAMES = ["pose_next", "delta"]


def export_step(net: ITNet, card: ModelCard, path: Path, opset: int = 20) -> Path:
    """Write ``path`` (.onnx): the step graph with ``card`` as metadata. Returns the path."""
    step = ExportableStep(net).eval()
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
    model = program.model_proto
    entry = model.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, card.model_dump_json()
    model.producer_name = "itnet"
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, str(path))
    onnx.checker.check_model(str(path))
    return path
