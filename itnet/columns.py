"""Reductions of a tall, narrow array (N, D) one column at a time.

numpy reduces ``points.min(axis=0)`` of an (N, 3) array element by element across the rows,
about twenty times slower than three contiguous reductions of its columns (280,000 points:
7.8 ms against 0.4 ms on this project's 2-core machine); ``points.mean(axis=0)`` as a
matrix-vector product is as fast. A scene's hot paths reduce clouds of 10^5-10^6 points.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def column_min(points: NDArray) -> NDArray:
    """(N, D) -> (D,): each column's minimum (N >= 1)."""
    return np.array([points[:, k].min() for k in range(points.shape[1])], dtype=points.dtype)


def column_max(points: NDArray) -> NDArray:
    """(N, D) -> (D,): each column's maximum (N >= 1)."""
    return np.array([points[:, k].max() for k in range(points.shape[1])], dtype=points.dtype)


def column_mean(points: NDArray) -> NDArray[np.float64]:
    """(N, D) -> (D,) float64: each column's mean (N >= 1)."""
    return np.ones(len(points)) @ np.asarray(points, dtype=np.float64) / len(points)
