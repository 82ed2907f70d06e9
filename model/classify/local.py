"""A classifier head that sees local shape: each point's features take the max over its nearest
neighbours (an edge convolution with one linear layer, as in DGCNN, on a fixed graph).

PointNet's head (``network.PointNetHead``) turns every point into features on its own and pools
once over the whole cloud, so a desk's side panel and a table's leg differ only through where
their points lie. Here every layer mixes in each point's ``k`` nearest neighbours (found once, in
the canonicalised coordinates), so a point's features describe the surface around it.

One layer, for point features ``x_i`` (C_in) and the neighbours ``N(i)`` of point i:

    h_i = relu(BN(A x_i + max_{j in N(i)} B x_j))

This is DGCNN's edge convolution ``max_j relu(BN(W [x_i, x_j - x_i]))`` with its max moved
inside: ``W [x_i, x_j - x_i] = (W_1 - W_2) x_i + W_2 x_j``, and the max over j commutes with
adding a term that does not depend on j. Moving it inside the BatchNorm and the ReLU (monotone
where BN's scale is positive) changes the function a little and makes it cheaper: the
products run once per point, not once per edge, and only a gather is done per edge (a
prototype's training step, batch 32 on 2 cores: 0.76 s against 1.06 s per edge).

Layers are chained and their outputs concatenated, turned into ``embedding`` features per point,
pooled by max and by mean, then an MLP with dropout gives the logits.
Shapes: B = batch, N = points, k = neighbours, C = channels.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from itnet.model.network import _mlp


def nearest_neighbours(points: Tensor, k: int) -> Tensor:
    """Points (B, N, 3) -> indices (B, N, k) of each point's k nearest points (itself included,
    and a repeated point's copies; k is clamped to N)."""
    squared = (points * points).sum(-1)  # (B, N)
    distances = squared[:, :, None] - 2 * points @ points.transpose(1, 2) + squared[:, None, :]
    return distances.topk(min(k, points.shape[1]), dim=-1, largest=False).indices


def neighbour_max(features: Tensor, neighbours: Tensor) -> Tensor:
    """Features (B, N, C), neighbour indices (B, N, k) -> (B, N, C): for every point and channel
    the largest value among its neighbours.

    With a gradient to compute, the max is found without one and the winners are then read
    again with one: the gradient flows to one neighbour per point and channel through a gather
    of (B, N, C) elements, not through the (B, N, k, C) block (a training step of the head about
    1.6 times as fast on 2 CPU cores, docs/classification.md). Without, the block is gathered
    and reduced (the exported graph's Gather + ReduceMax).
    """
    b, n, c = features.shape
    k = neighbours.shape[-1]
    flat = features.reshape(b * n, c)
    offsets = torch.arange(b, device=features.device)[:, None, None] * n
    index = (neighbours + offsets).reshape(b * n, k)  # (B*N, k) rows of ``flat``
    if not (torch.is_grad_enabled() and features.requires_grad):
        return flat[index].amax(dim=1).reshape(b, n, c)
    with torch.no_grad():
        winner = flat[index].max(dim=1).indices  # (B*N, C) which of the k neighbours
        rows = index.gather(1, winner)  # (B*N, C) its row in ``flat``
    return flat.gather(0, rows).reshape(b, n, c)


class NeighbourMaxLayer(nn.Module):
    """(B, N, C_in), neighbours (B, N, k) -> (B, N, C_out): relu(BN(A x_i + max_j B x_j))."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.centre = nn.Linear(c_in, c_out, bias=False)
        self.neighbour = nn.Linear(c_in, c_out, bias=False)
        self.norm = nn.BatchNorm1d(c_out)

    def forward(self, x: Tensor, neighbours: Tensor) -> Tensor:
        b, n, _ = x.shape
        mixed = self.centre(x) + neighbour_max(self.neighbour(x), neighbours)
        return torch.relu(self.norm(mixed.reshape(b * n, -1))).reshape(b, n, -1)


class LocalHead(nn.Module):
    """Points (B, N, 3) -> logits (B, outputs).

    ``channels``: the neighbour-max layers' widths, then the per-point embedding's (e.g.
    (64, 64, 128, 512)); ``head_channels``: the MLP after pooling; ``neighbours``: k.
    """

    def __init__(
        self,
        outputs: int,
        channels: tuple[int, ...],
        head_channels: tuple[int, ...],
        neighbours: int,
        dropout: float = 0.0,
    ) -> None:
        super().__init__()
        if len(channels) < 2:
            raise ValueError("a local head needs at least one neighbour layer and an embedding")
        self.neighbours = neighbours
        widths = [3, *channels[:-1]]
        self.layers = nn.ModuleList(
            NeighbourMaxLayer(c_in, c_out) for c_in, c_out in zip(widths[:-1], widths[1:])
        )
        self.embed = _mlp([sum(channels[:-1]), channels[-1]])
        self.head = _mlp([2 * channels[-1], *head_channels])
        self.dropout = nn.Dropout(dropout)
        self.out = nn.Linear(head_channels[-1], outputs)

    def forward(self, points: Tensor) -> Tensor:
        b, n, _ = points.shape
        neighbours = nearest_neighbours(points.float(), self.neighbours)
        x, layers = points, []
        for layer in self.layers:
            x = layer(x, neighbours)
            layers.append(x)
        embedded = self.embed(torch.cat(layers, dim=-1).reshape(b * n, -1)).reshape(b, n, -1)
        pooled = torch.cat([embedded.amax(dim=1), embedded.mean(dim=1)], dim=-1)
        return self.out(self.dropout(self.head(pooled)).float())
