"""Category symmetries about the canonical up axis (+y), and symmetry-aware rotation errors.

Pure numpy. A category's symmetry (its model card's ``symmetry``) names the rotations ``S`` about
the canonical origin under which its shapes look alike:

* ``none``: no turn (a chair: its back tells front from back),
* ``yaw180``: a half turn (C2; a table, a dresser: front and back alike at scan resolution),
* ``yaw90``: quarter turns (C4; a square night stand),
* ``yaw``: any turn (round objects: only the up axis and the centre are defined).

If ``T`` (T_canonical_from_input) is right, so is every ``S · T``: they put the object's centre at
the same place and differ only by the turn. Accuracy counts the best of them; the service
returns one of them and names the symmetry.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import FloatArray, axis_angle_to_matrix, rotation_error_deg

SYMMETRY_NAMES = ("none", "yaw180", "yaw90", "yaw")
YAW_SAMPLES = 360  # turns used for the continuous group 'yaw' (1 degree apart)


def symmetry_turns_deg(symmetry: str, yaw_samples: int = YAW_SAMPLES) -> NDArray[np.float64]:
    """The group's turns about +y in degrees, identity first: (G,)."""
    if symmetry not in SYMMETRY_NAMES:
        raise ValueError(f"unknown symmetry {symmetry!r} (known: {', '.join(SYMMETRY_NAMES)})")
    count = {"none": 1, "yaw180": 2, "yaw90": 4, "yaw": yaw_samples}[symmetry]
    return np.arange(count, dtype=np.float64) * (360.0 / count)


def symmetry_group(symmetry: str, yaw_samples: int = YAW_SAMPLES) -> FloatArray:
    """The group's rotations (G, 3, 3) about the canonical +y axis, identity first. Computed once
    per (symmetry, samples) and shared: the array is read-only (the ensemble mode fuses poses
    after every step, where building it cost more than the fusion itself)."""
    return _group(symmetry, yaw_samples)


@lru_cache(maxsize=32)
def _group(symmetry: str, yaw_samples: int) -> FloatArray:
    group = axis_angle_to_matrix(
        [0.0, 1.0, 0.0], np.radians(symmetry_turns_deg(symmetry, yaw_samples))
    )
    group.flags.writeable = False
    return group


def symmetric_rotation_error_deg(
    estimate: ArrayLike, truth: ArrayLike, symmetry: str, yaw_samples: int = YAW_SAMPLES
) -> FloatArray:
    """Rotations R_canonical_from_input (...x3x3 each) -> the smallest geodesic angle in degrees
    between the estimate and any equivalent truth ``S · R_truth`` (...)."""
    group = symmetry_group(symmetry, yaw_samples)  # (G, 3, 3)
    est = np.asarray(estimate, dtype=np.float64)[..., None, :, :]
    equivalent = group @ np.asarray(truth, dtype=np.float64)[..., None, :, :]  # (..., G, 3, 3)
    return np.min(rotation_error_deg(est, equivalent), axis=-1)
