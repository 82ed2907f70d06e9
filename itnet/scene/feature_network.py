"""A small network over a few measured features: what names a scene's objects
(``scene_classifier``) and what judges where a cluster holds two objects (``touching``).

One hidden layer under tanh, a softmax over its classes; its arrays are stored in JSON beside the
code that uses it and fitted by ``itnet.model.feature_network_fit``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

ARRAYS = ("mean", "scale", "hidden", "hidden_bias", "output", "output_bias")


@dataclass(frozen=True)
class FeatureNetwork:
    """features (F,) -> probabilities (C,): standardised by ``mean`` and ``scale`` (F,), then
    ``hidden`` (F, H) and ``hidden_bias`` (H,) under tanh, then ``output`` (H, C) and
    ``output_bias`` (C,) under softmax."""

    mean: NDArray[np.float64]
    scale: NDArray[np.float64]
    hidden: NDArray[np.float64]
    hidden_bias: NDArray[np.float64]
    output: NDArray[np.float64]
    output_bias: NDArray[np.float64]

    def probabilities(self, features: ArrayLike) -> NDArray[np.float64]:
        """features (..., F) -> probabilities (..., C)."""
        x = (np.asarray(features, dtype=np.float64) - self.mean) / self.scale
        logits = np.tanh(x @ self.hidden + self.hidden_bias) @ self.output + self.output_bias
        logits = logits - logits.max(axis=-1, keepdims=True)
        e = np.exp(logits)
        return e / e.sum(axis=-1, keepdims=True)

    def to_dict(self) -> dict[str, Any]:
        """Its arrays as lists (rounded to 7 decimals), by name."""
        return {k: np.round(getattr(self, k), 7).tolist() for k in ARRAYS}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FeatureNetwork:
        """The network whose arrays ``d`` holds by name (other keys are ignored)."""
        return cls(**{k: np.asarray(d[k], dtype=np.float64) for k in ARRAYS})


__all__ = ["ARRAYS", "FeatureNetwork"]
