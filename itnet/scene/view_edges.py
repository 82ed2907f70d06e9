"""Where a scene's view ends, and which of its edges a part of the scene reaches.

A camera sees a cone: a wall seen up to the top edge of the view goes on above it, and an
object whose points reach an edge goes on beyond it (a chair two metres before a level camera at
head height is seen from its seat up). The edges are measured on the scene's own points, in the
camera's frame (x right, y down, z ahead), as angles from the optical axis: for a depth image
they are its border pixels' rays, whatever their depth, so one rule serves images and clouds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from itnet.columns import percentiles

EDGES = ("top", "bottom", "left", "right")
REACH_PERCENT = 1.0  # a part reaches an edge where this share of its points (%) lies near it
# The edges are measured on every k-th point, at most this many: a depth image's points come
# row by row, so every row is still seen (under 1 ms at 640x480 instead of 6)
EDGE_POINTS = 20_000


def view_angles(points: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points (N, 3) in the camera's frame -> the angles (K,) below the optical axis (negative:
    above it) and right of it (negative: left) of each of the K points ahead of the camera."""
    ahead = points[points[:, 2] > 1e-6]
    return np.arctan2(ahead[:, 1], ahead[:, 2]), np.arctan2(ahead[:, 0], ahead[:, 2])


@dataclass(frozen=True)
class ViewEdges:
    """The view's edges as angles from the optical axis (radians): ``top`` and ``bottom`` below
    it (``top`` the least), ``left`` and ``right`` right of it (``left`` the least)."""

    top: float
    bottom: float
    left: float
    right: float

    @classmethod
    def of_points(cls, points: NDArray) -> ViewEdges | None:
        """The edges of the view that saw ``points`` (N, 3): the extreme angles of every k-th
        of them (at most EDGE_POINTS); None where none lies ahead of the camera."""
        step = max(1, len(points) // EDGE_POINTS)
        below, across = view_angles(np.asarray(points[::step], dtype=np.float64))
        if not len(below):
            return None
        return cls(float(below.min()), float(below.max()), float(across.min()),
                   float(across.max()))  # fmt: skip

    def reached(self, part: NDArray, within_deg: float = 1.0) -> tuple[str, ...]:
        """The edges (of ``EDGES``) that a part of the scene (K, 3) reaches: REACH_PERCENT of
        its points lie within ``within_deg`` of the edge."""
        below, across = view_angles(np.asarray(part, dtype=np.float64))
        if not len(below):
            return ()
        within = math.radians(within_deg)
        lo_b, hi_b = percentiles(below, [REACH_PERCENT, 100 - REACH_PERCENT])
        lo_a, hi_a = percentiles(across, [REACH_PERCENT, 100 - REACH_PERCENT])
        reached = {
            "top": lo_b <= self.top + within,
            "bottom": hi_b >= self.bottom - within,
            "left": lo_a <= self.left + within,
            "right": hi_a >= self.right - within,
        }
        return tuple(edge for edge in EDGES if reached[edge])


__all__ = ["EDGES", "ViewEdges", "view_angles"]
