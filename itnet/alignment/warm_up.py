"""A process's first alignment, made as cheap as every later one: what it would load, loaded ahead.

The first alignment a process serves pays for one-time work inside its budget: the alignment
modules and open3d imported (ICP; half a second on an idle machine, seconds on a loaded one
whose Python compiles the modules afresh), the calibration read, the first ICP call. A fresh
server's first ``POST /v1/align`` with a 5-second budget was refused when that work took 3.2 s
of it. ``warm_up`` does that work once on a made-up pair: the modules, the calibration, the
overlap measure and, where open3d imports, one ICP of a box onto its turned copy. It takes no
network step (the pose models' own warm-up seeds those), so it holds no admission: requests to
the other workers of ``itnet serve --workers N`` are not refused while it runs.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from itnet.geometry import apply_rigid, axis_angle_to_matrix
from itnet.model.distractors import box_surface

POINTS = 512
TURN_DEG = 30.0  # B is A turned this far about the vertical, and moved


def made_up_pair(seed: int = 0) -> tuple[NDArray, NDArray, NDArray]:
    """Two clouds (POINTS, 3) of a box's surface, 0.6 x 0.8 x 0.4 m, standing on y = 0, and
    T_b_from_a (4, 4): B is A turned ``TURN_DEG`` about y and moved 0.5 m along x."""
    a = box_surface(np.array([0.6, 0.8, 0.4]), POINTS, np.random.default_rng(seed))
    move = np.eye(4)
    move[:3, :3] = axis_angle_to_matrix([0.0, 1.0, 0.0], math.radians(TURN_DEG))
    move[:3, 3] = [0.5, 0.0, 0.0]
    return a, apply_rigid(move, a), move


def warm_up() -> bool:
    """Load what a first alignment needs (see the module); whether ICP ran (open3d imports)."""
    from itnet.alignment import estimators, pipeline  # noqa: F401  (what a first alignment imports)
    from itnet.alignment.choice import shipped
    from itnet.alignment.overlap import Cloud, overlap
    from itnet.alignment.refine import icp_point_to_plane, refine_wanted

    shipped()
    a, b, b_from_a = made_up_pair()
    overlap(b_from_a, Cloud(a), Cloud(b), 0.05)
    if not refine_wanted(None):
        return False
    icp_point_to_plane(a, b, b_from_a, 0.05)
    return True
