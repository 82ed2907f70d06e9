"""A process's first scene, done ahead: the whole scene path run once on a small made-up view.

The first scene a process finds pays for one-time work inside its budget: imports (Pillow, the
k-d tree and graph routines), the fitted files (the scene classifier, the cut judge, the scene
corrections) and the classifiers' first runs. On the example scene, the first call's
segmentation took 62 ms against 37 ms for the calls after it, and two of its three objects
were stopped by the budget, with 9 and 6 iterations instead of 10. ``warm_up`` runs the path
once (a 16-bit PNG of a floor with a box standing on it, decoded, segmented, classified and
posed), so that the first scene a caller sends is found as every later one is.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from itnet.pose.catalog import Catalog
from itnet.scene.camera import Intrinsics
from itnet.scene.depth_io import depth_to_png
from itnet.scene.inputs import from_png
from itnet.scene.pipeline import find_objects
from itnet.scene.request import SceneFinishing

WIDTH, HEIGHT = 160, 120
CAMERA = Intrinsics(140.0, 140.0, 79.5, 59.5)
CAMERA_HEIGHT_M = 1.4  # over the floor, level
BOX = ((-0.3, 0.3), (CAMERA_HEIGHT_M - 0.8, CAMERA_HEIGHT_M), 3.0)  # x range, y range, front z


def made_up_view() -> NDArray[np.uint16]:
    """A level camera 1.4 m over a floor, a box 0.6 m wide and 0.8 m tall standing 3 m ahead
    -> its depth image (HEIGHT, WIDTH) in millimetres (0: nothing seen, above the horizon)."""
    u, v = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    x, y = (u - CAMERA.cx) / CAMERA.fx, (v - CAMERA.cy) / CAMERA.fy  # each ray at z = 1
    with np.errstate(divide="ignore"):
        depth = np.where(y > 0, CAMERA_HEIGHT_M / np.where(y > 0, y, 1.0), np.inf)  # the floor
    (x_lo, x_hi), (y_lo, y_hi), front = BOX
    on_box = (x * front >= x_lo) & (x * front <= x_hi) & (y * front >= y_lo) & (y * front <= y_hi)
    depth = np.where(on_box, np.minimum(depth, front), depth)
    depth = np.where(depth <= 8.0, depth, 0.0)
    return np.round(depth * 1000).astype(np.uint16)


def warm_up(catalog: Catalog | None = None) -> None:
    """Find the objects of ``made_up_view`` with ``catalog`` (default: the shipped models), with
    a budget that lets every step run: afterwards a scene costs what it will cost every time.
    The box is named whatever the scene classifier thinks of it (a plain box is none of the
    categories), so that its pose runs too."""
    png = depth_to_png(made_up_view())
    find_objects(from_png(png, CAMERA), budget_ms=2000.0, catalog=catalog,
                 finishing=SceneFinishing(unknown=False))  # fmt: skip
