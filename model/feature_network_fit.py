"""Fit a ``FeatureNetwork`` (``itnet.scene.feature_network``) to labelled features, and the
samples' cache the fitting commands share."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from itnet.scene.feature_network import FeatureNetwork


def fit_network(
    features: NDArray, labels: list[str], classes: tuple[str, ...], hidden: int, weight_decay: float,
    epochs: int, seed: int = 0,
) -> FeatureNetwork:  # fmt: skip
    """Features (S, F) and their labels (S,), each one of ``classes`` -> the network: full-batch
    Adam (lr 0.01, weight decay) on the cross-entropy, ``epochs`` steps from a seeded start."""
    import torch

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


class FeatureFitConfig(BaseModel):
    """What every fit of a feature network shares: the network (hidden units, weight decay,
    epochs), the validation scenes its threshold is chosen on, the data, the samples' caches and
    the file written. Each fit declares its own defaults for these."""

    model_config = ConfigDict(extra="forbid")

    hidden: int = Field(default=32, ge=1, description="hidden units (chosen on validation scenes)")
    weight_decay: float = Field(default=1e-4, ge=0, description="chosen on validation")
    epochs: int = Field(default=1000, ge=1, description="chosen on validation")
    threshold_scenes: int = Field(
        default=300, ge=1, description="validation scenes the threshold is chosen on"
    )
    threshold_seed: int = Field(default=5, description="their seed")
    data: Path = Field(default=Path("../shared/data/modelnet10"), description="ModelNet10 root")
    cache: Path = Field(default=Path("cache/scenes"), description="the shapes' cache")
    samples: Path | None = Field(
        default=None,
        description="an .npz of the scenes' samples: read where it exists, else written",
    )
    threshold_samples: Path | None = Field(
        default=None, description="the same for the validation scenes"
    )
    out: Path = Field(description="the file written")


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


__all__ = ["FeatureFitConfig", "cached", "fit_network", "write_fitted"]
