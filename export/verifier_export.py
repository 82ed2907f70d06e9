"""Export a trained verifier to one ONNX graph: a run's points where its pose puts them
(B, N, 3), normalised canonical frame -> the logit of the pose being right (B,).

The network is ``PointNetHead`` with one output, folded as the classifier's heads are
(``FoldedPointNet``: BatchNorm into the weights, max-pool over the innermost axis).
"""

from __future__ import annotations

from pathlib import Path

from torch import Tensor, nn

from itnet.export.classifier_export import FoldedPointNet, export_points_graph
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
    return export_points_graph(ExportableVerifier(net), "logits", card, path, opset)
