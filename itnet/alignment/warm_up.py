"""A process's first alignment, done ahead: the alignment path run once on a made-up pair.

The first alignment a process serves pays for one-time work inside its budget: the alignment
modules and open3d imported (ICP; half a second on an idle machine, seconds on a loaded one
whose Python compiles the modules afresh), the calibration read, the first k-d trees and ICP
call. A fresh server's first ``POST /v1/align`` with a 5-second budget was refused when that
work took 3.2 s of it. ``warm_up`` aligns a made-up box with a turned copy of itself once with
the catalog's default model, so that the first alignment a caller sends costs what every later
one does.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from itnet.geometry import apply_rigid, axis_angle_to_matrix
from itnet.pose.catalog import Catalog

POINTS = 512
TURN_DEG = 30.0  # B is A turned this far about the vertical, and moved


def made_up_pair(seed: int = 0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two clouds (POINTS, 3) of a box's surface, 0.6 x 0.8 x 0.4 m: A, and B, the same points
    turned ``TURN_DEG`` about y and moved 0.5 m along x."""
    rng = np.random.default_rng(seed)
    half = np.array([0.3, 0.4, 0.2])
    points = rng.uniform(-1.0, 1.0, size=(POINTS, 3))
    face = rng.integers(3, size=POINTS)
    points[np.arange(POINTS), face] = np.sign(points[np.arange(POINTS), face])
    a = points * half
    move = np.eye(4)
    move[:3, :3] = axis_angle_to_matrix([0.0, 1.0, 0.0], math.radians(TURN_DEG))
    move[:3, 3] = [0.5, 0.0, 0.0]
    return a, apply_rigid(move, a)


def warm_up(catalog: Catalog) -> None:
    """Align ``made_up_pair`` once with ``catalog``'s default model (ICP where open3d imports),
    under a budget that lets every step run."""
    from itnet.alignment import align
    from itnet.alignment.request import AlignRequest

    a, b = made_up_pair()
    align(catalog, a, b, AlignRequest(budget_ms=2000.0))
