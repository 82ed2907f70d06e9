"""Widen a trained IT-Net without changing what it computes (Net2WiderNet, Chen et al., ICLR 2016).

A wider network trained from scratch has to relearn everything a narrow one already knows; this
one starts as the narrow network's function and spends its steps on what the extra units add.
Each hidden layer's unit ``i`` of the wider network copies unit ``i mod old_width`` (its weights
and BatchNorm, statistics included), and the next layer divides the weights it reads from a copied
unit among its copies. Every layer is Linear (no bias) → BatchNorm → ReLU, and the point MLP's
max-pool is taken per channel, so copies stay equal through it and the sums are unchanged.

Copies that stay equal get equal gradients and never become different units (with Adam, not even
for unequal splits), so the copies' input weights get a little noise (``noise`` times the layer's
weight spread): the function moves by about that much, and the units are free to part.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from itnet.model.network import ITNet, NetworkConfig


def can_widen(narrow: NetworkConfig, wide: NetworkConfig) -> bool:
    """Whether ``wide`` is ``narrow`` with some layers wider: the same depth, rotation and
    initialisation, every width at least the narrow one's, and not the same network."""
    if narrow.rotation != wide.rotation or narrow == wide:
        return False
    pairs = [
        (narrow.point_channels, wide.point_channels),
        (narrow.head_channels, wide.head_channels),
    ]
    return all(len(a) == len(b) and all(x <= y for x, y in zip(a, b)) for a, b in pairs)


def _linears(net: ITNet) -> list[tuple[nn.Linear, nn.BatchNorm1d | None]]:
    """The regressor's layers in order, each with the BatchNorm after it (None for the output)."""
    regressor = net.regressor
    layers: list[tuple[nn.Linear, nn.BatchNorm1d | None]] = []
    for mlp in (regressor.point_mlp, regressor.head):
        modules = list(mlp)
        for linear, norm in zip(modules[0::3], modules[1::3]):
            assert isinstance(linear, nn.Linear) and isinstance(norm, nn.BatchNorm1d)
            layers.append((linear, norm))
    layers.append((regressor.out, None))
    return layers


@torch.no_grad()
def widen(net: ITNet, config: NetworkConfig, noise: float = 0.01, seed: int = 0) -> ITNet:
    """``net`` -> a new ITNet of ``config`` (wider, ``can_widen``) that computes the same poses,
    up to the copies' ``noise``; in eval mode, like ``load_checkpoint``'s networks."""
    if not can_widen(net.config, config):
        raise ValueError(
            f"cannot widen {net.config} to {config}: same depth and rotation, no layer narrower"
        )
    wide = ITNet(config)
    generator = torch.Generator().manual_seed(seed)
    # which narrow input each wide input reads, and how many wide inputs read that narrow one
    source: Tensor = torch.arange(3)
    for (old, old_norm), (new, new_norm) in zip(_linears(net), _linears(wide)):
        width, old_width = new.out_features, old.out_features
        rows = torch.arange(width) % old_width
        shares = torch.bincount(source, minlength=old.in_features).to(old.weight.dtype)
        weight = old.weight[rows][:, source] / shares[source]
        if width > old_width and noise > 0:
            jitter = torch.randn(width - old_width, weight.shape[1], generator=generator)
            weight[old_width:] += noise * old.weight.std() * jitter.to(weight.dtype)
        new.weight.copy_(weight)
        if old.bias is not None and new.bias is not None:
            new.bias.copy_(old.bias[rows])
        if old_norm is not None and new_norm is not None:
            for name in ("weight", "bias", "running_mean", "running_var"):
                getattr(new_norm, name).copy_(getattr(old_norm, name)[rows])
            if (
                new_norm.num_batches_tracked is not None
                and old_norm.num_batches_tracked is not None
            ):
                new_norm.num_batches_tracked.copy_(old_norm.num_batches_tracked)
        source = rows
    return wide.eval()
