"""Fit a ``FeatureNetwork`` (``itnet.scene.feature_network``) to labelled features, and the
samples' cache the fitting commands share."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from itnet.scene.feature_network import FeatureNetwork


def fit_network(
    features: NDArray, labels: list[str], classes: tuple[str, ...], hidden: int, weight_decay: float,
    epochs: int, seed: int = 0,
) -> FeatureNetwork:  # fmt: skip
    """Features (S, F) and their labels (S,), each one of ``classes`` -> the network: full-batch
    Adam (lr 0.01, weight decay) on the cross-entropy, ``epochs`` steps from a seeded start."""
    torch.manual_seed(seed)
    mean, scale = features.mean(0), features.std(0) + 1e-6
    x = torch.tensor((features - mean) / scale, dtype=torch.float32)
    y = torch.tensor([classes.index(label) for label in labels])
    first, last = torch.nn.Linear(x.shape[1], hidden), torch.nn.Linear(hidden, len(classes))
    net = torch.nn.Sequential(first, torch.nn.Tanh(), last)
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-2, weight_decay=weight_decay)
    for _ in range(epochs):
        optimiser.zero_grad()
        loss = torch.nn.functional.cross_entropy(net(x), y)
        loss.backward()
        optimiser.step()

    def array(t: torch.Tensor) -> NDArray[np.float64]:
        return t.detach().numpy().astype(np.float64)

    return FeatureNetwork(mean, scale, array(first.weight.T), array(first.bias),
                          array(last.weight.T), array(last.bias))  # fmt: skip


def cached(
    path: Path | None, collect: Callable[[], tuple[NDArray[np.float64], list[str]]]
) -> tuple[NDArray[np.float64], list[str]]:
    """Samples (features (S, F), labels (S,)) read from the .npz at ``path`` where it exists,
    else collected (and written there, where a path is given)."""
    if path is not None and path.exists():
        with np.load(path) as saved:
            return saved["features"], [str(v) for v in saved["labels"]]
    features, labels = collect()
    if path is not None:
        np.savez(path, features=features, labels=np.array(labels))
    return features, labels


__all__ = ["cached", "fit_network"]
