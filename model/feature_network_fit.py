"""Fit a ``FeatureNetwork`` (``itnet.scene.feature_network``) to labelled features, and the
samples' cache the fitting commands share."""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

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


def add_fit_arguments(
    parser: argparse.ArgumentParser, hidden: int, weight_decay: float, epochs: int,
    threshold_seed: int, out: Path, threshold_help: str,
) -> None:  # fmt: skip
    """The options every fitting command shares, with its defaults: the network's (hidden,
    weight decay, epochs), the validation scenes its threshold is chosen on, the data, the
    samples' caches and the file written."""
    parser.add_argument("--hidden", type=int, default=hidden, help="chosen on validation scenes")
    parser.add_argument("--weight-decay", type=float, default=weight_decay,
                        help="chosen on validation")  # fmt: skip
    parser.add_argument("--epochs", type=int, default=epochs, help="chosen on validation")
    parser.add_argument("--threshold-scenes", type=int, default=300, help=threshold_help)
    parser.add_argument("--threshold-seed", type=int, default=threshold_seed)
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache/scenes"))
    parser.add_argument("--samples", type=Path, default=None,
                        help="an .npz of the scenes' samples: read where it exists, else written")  # fmt: skip
    parser.add_argument("--threshold-samples", type=Path, default=None,
                        help="the same for the validation scenes")  # fmt: skip
    parser.add_argument("--out", type=Path, default=out)


class Fitted(Protocol):
    threshold: float
    fit: dict[str, Any]

    def to_dict(self) -> dict[str, Any]: ...


def write_fitted(path: Path, fitted: Fitted, started: float) -> None:
    """Write a fitted network's file (JSON, one line) and say how it was fitted, its threshold
    and how long it took since ``started`` (``time.perf_counter()``)."""
    path.write_text(json.dumps(fitted.to_dict()) + "\n")
    print(json.dumps(fitted.fit, indent=1))
    print(
        f"threshold {fitted.threshold:.4f}; wrote {path} in {time.perf_counter() - started:.0f} s"
    )


__all__ = ["add_fit_arguments", "cached", "fit_network", "write_fitted"]
