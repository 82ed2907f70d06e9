"""How well cloud A, moved by candidate poses, lies on cloud B: symmetric overlap and its RMSE.

Pure numpy + scipy (KD-trees built once per cloud, queried for every pose at once): the
alignment scores tens of hypotheses per pair, so one query per hypothesis and direction, not a
Python loop per point. Frames: every pose is T_b_from_a (H, 4, 4), B's units.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from itnet.preprocess import cap_points


class Cloud:
    """A cloud (M, 3) and its KD-tree, built once for many queries."""

    def __init__(self, points: ArrayLike) -> None:
        self.points = np.asarray(points, dtype=np.float64)
        self.tree = cKDTree(self.points)


def sample(points: NDArray, count: int | None, seed: int) -> NDArray:
    """``count`` points (count, 3) of a cloud (N, 3), a seeded random subset (all if fewer or
    ``count`` is None): ``itnet.preprocess.cap_points`` with a generator seeded here."""
    if count is None:
        return points
    return np.asarray(cap_points(points, count, np.random.default_rng(seed)))


def overlap(
    poses: ArrayLike,
    a: Cloud,
    b: Cloud,
    distance: float,
    points: int | None = None,
    seed: int = 0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Poses T_b_from_a (H, 4, 4) -> (fitness (H,), rmse (H,)).

    fitness: mean of the share of moved-A points with a B point within ``distance`` and the
    share of B points with a moved-A point within it (B moved back by the inverse pose: the
    same distances, and A's tree serves every pose), in [0, 1]. rmse: RMS distance of those
    inlier pairs (``inf`` where there are none). ``points``: measure each share on that many
    points of its side (a seeded random subset), against the whole other cloud.
    """
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    rot, shift = p[:, :3, :3], p[:, :3, 3]
    from_a, from_b = sample(a.points, points, seed), sample(b.points, points, seed + 1)
    forward = from_a[None] @ rot.transpose(0, 2, 1) + shift[:, None]  # A in B's frame
    back = (from_b[None] - shift[:, None]) @ rot  # B in A's frame
    d_ab = b.tree.query(forward.reshape(-1, 3), distance_upper_bound=distance)[0]
    d_ba = a.tree.query(back.reshape(-1, 3), distance_upper_bound=distance)[0]
    d_ab, d_ba = d_ab.reshape(len(p), -1), d_ba.reshape(len(p), -1)
    near_ab, near_ba = np.isfinite(d_ab), np.isfinite(d_ba)
    fitness = 0.5 * (near_ab.mean(axis=1) + near_ba.mean(axis=1))
    squares = np.where(near_ab, d_ab, 0.0) ** 2
    total = squares.sum(axis=1) + (np.where(near_ba, d_ba, 0.0) ** 2).sum(axis=1)
    count = near_ab.sum(axis=1) + near_ba.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rmse = np.where(count > 0, np.sqrt(total / np.maximum(count, 1)), np.inf)
    return fitness, rmse


def overlap_score(
    points_a: ArrayLike,
    points_b: ArrayLike,
    b_from_a: ArrayLike,
    inlier_distance: float,
    points: int | None = None,
) -> tuple[float, float]:
    """One pose: how well A (N, 3), moved by T_b_from_a (4x4), lies on B (M, 3) ->
    (fitness, rmse); see ``overlap``."""
    fitness, rmse = overlap(b_from_a, Cloud(points_a), Cloud(points_b), inlier_distance, points)
    return float(fitness[0]), float(rmse[0])
