"""The input normalisation shared by training and the runtime (one place, so they cannot drift).

A cloud ``p`` (Nx3, any unit) becomes ``x = (p - c) / s`` with

* ``c`` = the centroid of the cloud (mean of its points),
* ``s`` = its RMS radius about the centroid, ``sqrt(mean ||p - c||^2)``.

Both come from the partial cloud itself, never from ground truth. The network works in that
normalised frame: it predicts ``T_n`` with ``R x + t_n`` = canonical point / s, so the canonical
frame keeps the input's scale. Back in the input's units::

    T_canonical_from_input = [R | s * t_n - R c]        (pose_from_normalized)
    t_n = (t + R c) / s                                  (pose_to_normalized)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import FloatArray


class DegenerateCloudError(ValueError):
    """The cloud has no spatial extent (all points equal, or nearly so)."""


@dataclass(frozen=True)
class Normalization:
    """Centre (3,) and scale of a cloud, in the cloud's own units."""

    center: NDArray[np.float64]
    scale: float

    def apply(self, points: ArrayLike) -> NDArray[np.float32]:
        """Points (Nx3, input units) -> normalised points (Nx3, float32)."""
        return ((np.asarray(points, dtype=np.float64) - self.center) / self.scale).astype(
            np.float32
        )


def estimate_normalization(points: ArrayLike, rel_eps: float = 1e-9) -> Normalization:
    """Centroid and RMS radius of a cloud (Nx3). Raises DegenerateCloudError for a point-like cloud."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0:
        raise DegenerateCloudError("the cloud is degenerate: it has no points")
    center = p.mean(axis=0)
    offsets = p - center
    scale = float(np.sqrt(np.einsum("ij,ij->", offsets, offsets) / len(p)))
    magnitude = max(float(np.abs(center).max()), 1.0)
    if not np.isfinite(scale) or scale <= rel_eps * magnitude:
        raise DegenerateCloudError(
            f"the cloud is degenerate: its points span {scale:.3g} units around their centroid"
        )
    return Normalization(center=center, scale=scale)


def pose_from_normalized(pose_normalized: ArrayLike, norm: Normalization) -> FloatArray:
    """T_n (...x4x4, normalised frame) -> T_canonical_from_input (...x4x4, input units)."""
    t_n = np.array(pose_normalized, dtype=np.float64)
    r = t_n[..., :3, :3]
    t_n[..., :3, 3] = norm.scale * t_n[..., :3, 3] - r @ norm.center
    return t_n


def pose_to_normalized(pose: ArrayLike, norm: Normalization) -> FloatArray:
    """T_canonical_from_input (...x4x4, input units) -> T_n (...x4x4, normalised frame)."""
    t = np.array(pose, dtype=np.float64)
    r = t[..., :3, :3]
    t[..., :3, 3] = (t[..., :3, 3] + r @ norm.center) / norm.scale
    return t


def cap_points(points: ArrayLike, count: int, rng: np.random.Generator) -> NDArray:
    """At most ``count`` points (K x3, K = min(N, count)): a seeded random subset of a larger
    cloud, a smaller one whole and in order.

    What the runtime feeds the network. Padding a small cloud to ``count`` with repeats (as
    ``resample`` does for fixed-size training batches) gives the same max-pooled feature, hence
    the same pose, but costs a step time proportional to ``count`` instead of N.
    """
    p = np.asarray(points)
    if len(p) <= count:
        return p
    return p[rng.choice(len(p), size=count, replace=False)]


def shuffled_subset(points: ArrayLike, count: int, rng: np.random.Generator) -> NDArray:
    """At most ``count`` points (K x3, K = min(N, count)) in random order: a seeded random subset
    of a larger cloud, a smaller one whole and shuffled.

    What a classifier graph is fed: its canonicaliser may look at only the first points of its
    input (``ClassifierCard.canonical_points``), which must then be a random sample of the
    cloud, not the first rows of a depth image.
    """
    p = np.asarray(points)
    return p[rng.permutation(len(p))] if len(p) <= count else cap_points(p, count, rng)


def resample(points: ArrayLike, count: int, rng: np.random.Generator) -> NDArray:
    """Exactly ``count`` points (count x3): a random subset, or all points plus random repeats.

    Repeats do not change a max-pooled PointNet feature, so a small cloud loses nothing.
    """
    p = np.asarray(points)
    n = len(p)
    if n >= count:
        return p[rng.choice(n, size=count, replace=False)]
    extra = rng.choice(n, size=count - n, replace=True)
    return np.concatenate([p, p[extra]], axis=0)
