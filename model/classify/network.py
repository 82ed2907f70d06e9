"""A PointNet classifier with a spatial transformer in front (the paper's Section 4.2).

Transformers (``TRANSFORMERS``), each iterated ``iterations`` times with one shared regressor:

* ``none``: the points go straight to the classifier.
* ``tnet``: PointNet's T-Net, a 3x3 affine matrix predicted from the points (identity init).
  With ``regularizer > 0`` the loss adds ``w * sum_k ||A_k A_k^T - I||^2`` over the predicted
  updates ``A_k`` (PointNet's orthogonality term; the paper's "T-Net reg", w = 0.001).
* ``itnet``: IT-Net's rigid step (``model.network.ITNet``: unit quaternion + translation,
  identity init), the same module the pose models train.

With ``up_weight > 0`` (IT-Net only; not the paper's, whose transformers learn from the class
loss alone) training passes each view's up axis ``u``, and IT-Net learns from
``w * mean_k (1 - (R_k u)_y)`` alone: every iteration's rotation ``R_k`` should turn the view's
up onto +y, so that the classifier sees standing objects and only their yaw is left free. The
class loss then trains the classifier only (the pose it sees is detached): trained jointly, the
class loss's gradient drowned the up term (it did not fall in 1,800 steps on ModelNet10). The
exported graph is the same either way.

Iterations compose as in IT-Net: ``T_k = dT_k @ T_(k-1)``, the regressor sees the input moved by
``T_(k-1)`` with the gradient stopped there (the paper's choice), and the classifier sees the
input moved by the final ``T_K``. Shapes: B = batch, N = points, C = classes.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from itnet.model.classify.local import LocalHead
from itnet.model.network import ITNet, NetworkConfig, _mlp, apply_pose

TRANSFORMERS = ("none", "tnet", "itnet")
HEADS = ("pointnet", "local")  # the classifier after the transformer (``local.py``)
TRANSFORMER_PREFIXES = ("itnet.", "tnet.")  # the transformer's entries in a state dict
REGULARIZER_WEIGHT = 0.001  # PointNet's and the paper's weight of the orthogonality term


@dataclass(frozen=True)
class ClassifierConfig:
    """Architecture. Defaults: the paper's PointNet widths, 10 classes, no transformer."""

    classes: int = 10
    transformer: str = "none"
    iterations: int = 1
    regularizer: float = 0.0  # weight of ||A A^T - I||^2 (tnet only)
    up_weight: float = 0.0  # weight of the up-axis term (itnet only; needs ``up`` in training)
    point_channels: tuple[int, ...] = (64, 128, 1024)
    head_channels: tuple[int, ...] = (512, 256)
    dropout: float = 0.3  # PointNet's keep probability 0.7
    # the transformer finds its pose from the first this many points (fed in random order) and
    # moves them all; None: from every point (``ClassifierCard.canonical_points``)
    canonical_points: int | None = None
    # the classifier: "pointnet" (the paper's) or "local" (``local.LocalHead``: every layer
    # mixes in each point's ``neighbours`` nearest points; ``local_channels``: its layers' widths,
    # then the per-point embedding's)
    head: str = "pointnet"
    local_channels: tuple[int, ...] = (64, 64, 128, 512)
    neighbours: int = 16

    def __post_init__(self) -> None:
        if self.head not in HEADS:
            raise ValueError(f"head must be one of {HEADS}, not {self.head!r}")
        if self.transformer not in TRANSFORMERS:
            raise ValueError(f"transformer must be one of {TRANSFORMERS}, not {self.transformer!r}")
        if self.transformer != "none" and self.iterations < 1:
            raise ValueError("a transformer needs at least one iteration")
        if self.up_weight and self.transformer != "itnet":
            raise ValueError("up_weight supervises IT-Net's rotation: transformer must be itnet")
        if self.canonical_points is not None and self.canonical_points < 1:
            raise ValueError("canonical_points must be at least 1")


def transformer_state(state: dict[str, Tensor]) -> dict[str, Tensor]:
    """A classifier's state dict -> its transformer's entries (weights, BatchNorm statistics)."""
    return {k: v for k, v in state.items() if k.startswith(TRANSFORMER_PREFIXES)}


class PointNetHead(nn.Module):
    """Points (B, N, 3) -> (B, outputs): shared MLP, max-pool, MLP (+ dropout), linear."""

    def __init__(
        self,
        outputs: int,
        point_channels: tuple[int, ...],
        head_channels: tuple[int, ...],
        dropout: float = 0.0,
    ) -> None:
        super().__init__()
        self.point_mlp = _mlp([3, *point_channels])
        self.head = _mlp([point_channels[-1], *head_channels])
        self.dropout = nn.Dropout(dropout)
        self.out = nn.Linear(head_channels[-1], outputs)

    def forward(self, points: Tensor) -> Tensor:
        b, n, _ = points.shape
        features = self.point_mlp(points.reshape(b * n, 3)).reshape(b, n, -1)
        return self.out(self.dropout(self.head(features.amax(dim=1))).float())


class AffineTNet(nn.Module):
    """T-Net: points (B, N, 3) -> a 3x3 matrix (B, 3, 3), identity at initialisation."""

    def __init__(self, config: ClassifierConfig) -> None:
        super().__init__()
        self.regressor = PointNetHead(9, config.point_channels, config.head_channels)
        nn.init.zeros_(self.regressor.out.weight)
        with torch.no_grad():
            self.regressor.out.bias.copy_(torch.eye(3).flatten())

    def forward(self, points: Tensor) -> Tensor:
        return self.regressor(points).reshape(-1, 3, 3)


class Classifier(nn.Module):
    """Transformer (or none) + PointNet classifier. ``forward`` -> (logits (B, C), the
    regulariser term (scalar, 0 unless tnet with a weight))."""

    def __init__(self, config: ClassifierConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or ClassifierConfig()
        self.tnet = AffineTNet(config) if config.transformer == "tnet" else None
        self.itnet = (
            ITNet(NetworkConfig(config.point_channels, config.head_channels))
            if config.transformer == "itnet"
            else None
        )
        self.classifier: PointNetHead | LocalHead = (
            LocalHead(
                config.classes,
                config.local_channels,
                config.head_channels,
                config.neighbours,
                config.dropout,
            )
            if config.head == "local"
            else PointNetHead(
                config.classes, config.point_channels, config.head_channels, config.dropout
            )
        )

    def canonicalize(self, points: Tensor, up: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Points (B, N, 3), up axes (B, 3) or None -> (the points the classifier sees
        (B, N, 3), the transformer's extra loss terms (scalar))."""
        zero = points.new_zeros(())
        k = self.config.canonical_points
        seen = points if k is None else points[:, :k]  # what the transformer reads
        if self.itnet is not None:
            poses = self.itnet(seen, self.config.iterations, stop_gradient=True)
            if self.config.up_weight > 0:  # IT-Net learns from the up term alone
                penalty = zero
                if up is not None:  # (R_k u)_y = row 1 of R_k . u: 1 when up lands on +y
                    lifted = torch.stack([(p[:, 1, :3] * up).sum(-1) for p in poses])  # (K, B)
                    penalty = self.config.up_weight * (1.0 - lifted).mean()
                return apply_pose(poses[-1].detach(), points), penalty
            return apply_pose(poses[-1], points), zero
        if self.tnet is not None:
            eye = torch.eye(3, dtype=points.dtype, device=points.device)
            total, penalty = eye.expand(len(points), 3, 3), zero
            for _ in range(self.config.iterations):
                moved = seen @ total.detach().transpose(1, 2)
                update = self.tnet(moved)
                total = update @ total
                penalty = (
                    penalty + (update @ update.transpose(1, 2) - eye).square().sum((1, 2)).mean()
                )
            return points @ total.transpose(1, 2), self.config.regularizer * penalty
        return points, zero

    def forward(self, points: Tensor, up: Tensor | None = None) -> tuple[Tensor, Tensor]:
        moved, penalty = self.canonicalize(points, up)
        return self.classifier(moved), penalty


VARIANTS: dict[str, ClassifierConfig] = {
    "none": ClassifierConfig(),
    "tnet-1": ClassifierConfig(transformer="tnet", iterations=1),
    "tnet-2": ClassifierConfig(transformer="tnet", iterations=2),
    "tnet-reg-1": ClassifierConfig(
        transformer="tnet", iterations=1, regularizer=REGULARIZER_WEIGHT
    ),
    "tnet-reg-2": ClassifierConfig(
        transformer="tnet", iterations=2, regularizer=REGULARIZER_WEIGHT
    ),
    "itnet-1": ClassifierConfig(transformer="itnet", iterations=1),
    "itnet-2": ClassifierConfig(transformer="itnet", iterations=2),
}
"""The table's rows (the paper's Table 3, PointNet columns)."""

PAPER_ACCURACY = {
    "none": 59.97,
    "tnet-1": 66.04,
    "tnet-2": 35.13,
    "tnet-reg-1": 65.84,
    "tnet-reg-2": 67.06,
    "itnet-1": 68.72,
    "itnet-2": 69.94,
}
"""The paper's top-1 accuracy (%) on Partial ModelNet40 with PointNet, by row."""
