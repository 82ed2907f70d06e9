"""What a run hands back: one ``Estimate`` per iteration and the JSON form of a pose.

``T_canonical_from_input`` (4x4, row-major) maps a point of the cloud as sent into the category's
canonical frame, translation in the cloud's own units; quaternions travel in both orders.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from itnet.geometry import matrix_to_quat_wxyz, quat_wxyz_to_xyzw
from itnet.preprocess import Normalization, pose_from_normalized


@dataclass(frozen=True)
class Estimate:
    """The pose after ``iteration`` steps. ``pose`` is T_canonical_from_input (4x4, input units),
    computed from the normalised pose when first read (the loop itself never needs it)."""

    iteration: int
    pose_normalized: NDArray[np.float32]  # (4, 4), the network's frame
    normalization: Normalization
    elapsed_ms: float
    update_rotation_deg: float  # size of this iteration's update
    update_translation: float  # in the input's units

    @cached_property
    def pose(self) -> NDArray[np.float64]:
        pose = pose_from_normalized(self.pose_normalized.astype(np.float64), self.normalization)
        return np.asarray(pose, dtype=np.float64)

    def to_dict(self, quat_wxyz: NDArray[np.float64] | None = None) -> dict:
        """The JSON form (``quat_wxyz``: the pose's quaternion, if already computed)."""
        return {
            "iteration": self.iteration,
            **pose_fields(self.pose, quat_wxyz),
            "elapsed_ms": round(self.elapsed_ms, 3),
            "update_rotation_deg": round(self.update_rotation_deg, 5),
            "update_translation": self.update_translation,
        }


def estimates_to_dicts(estimates: Sequence[Estimate]) -> list[dict]:
    """``Estimate.to_dict`` of each, their quaternions converted in one batch (numpy's per-call
    cost, paid once instead of once an estimate, inside the budget)."""
    if not estimates:
        return []
    quats = matrix_to_quat_wxyz(np.stack([e.pose[:3, :3] for e in estimates]))
    return [e.to_dict(q) for e, q in zip(estimates, quats, strict=True)]


def pose_fields(pose: NDArray[np.float64], quat_wxyz: NDArray[np.float64] | None = None) -> dict:
    """The JSON form of a pose: matrix, both quaternion orders, translation (``quat_wxyz``: the
    rotation's quaternion, if already computed)."""
    quat = matrix_to_quat_wxyz(pose[:3, :3]) if quat_wxyz is None else quat_wxyz
    return {
        "T_canonical_from_input": pose.tolist(),
        "quat_wxyz": quat.tolist(),
        "quat_xyzw": quat_wxyz_to_xyzw(quat).tolist(),
        "translation": pose[:3, 3].tolist(),
    }
