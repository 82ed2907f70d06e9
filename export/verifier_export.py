"""Export a trained verifier to one ONNX graph: a run's points where its pose puts them
(B, N, 3), normalised canonical frame -> the logit of the pose being right (B,).

The network is ``PointNetHead`` with one output, folded as the classifier's heads are
(``FoldedPointNet``: BatchNorm into the weights, max-pool over the innermost axis).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from itnet.export.classifier_export import FoldedPointNet
from itnet.export.onnx_export import save_with_card
from itnet.model.classify.network import PointNetHead
from itnet.model_card import VerifierCard


class ExportableVerifier(nn.Module):
    """(B, N, 3) -> logits (B,)."""

    def __init__(self, net: PointNetHead) -> None:
        super().__init__()
        self.folded = FoldedPointNet(net.eval())

    def forward(self, points: Tensor) -> Tensor:
        return self.folded(points)[:, 0]


def export_verifier(net: PointNetHead, card: VerifierCard, path: Path, opset: int = 20) -> Path:
    """Write ``path`` (.onnx): the verifier graph with ``card`` as metadata. Returns the path."""
    graph = ExportableVerifier(net).eval()
    batch, count = torch.export.Dim("batch", min=1, max=4096), torch.export.Dim("points", min=1)
    program = torch.onnx.export(
        graph,
        (torch.randn(2, 64, 3),),
        dynamo=True,
        opset_version=opset,
        input_names=["points"],
        output_names=["logits"],
        dynamic_shapes={"points": {0: batch, 1: count}},
        external_data=False,
        verbose=False,
    )
    return save_with_card(program.model_proto, card, path)  # type: ignore[union-attr]
