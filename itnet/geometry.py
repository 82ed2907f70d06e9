"""Rigid-transform math on numpy arrays: the one place for rotations, quaternions and 4x4 poses.

Conventions used throughout itnet:

* A pose is a 4x4 homogeneous matrix ``T_a_from_b`` that maps a point expressed in frame ``b``
  to frame ``a``: ``p_a = R @ p_b + t``.
* Quaternions are unit quaternions. ``wxyz`` puts the scalar first (the network's output, Eigen),
  ``xyzw`` puts it last (ROS, SciPy). Every function says which one it takes.
* Every function accepts any leading batch shape (``...``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.floating]


def quat_wxyz_to_xyzw(quat: ArrayLike) -> FloatArray:
    """(...x4, WXYZ) -> (...x4, XYZW)."""
    q = np.asarray(quat)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def quat_xyzw_to_wxyz(quat: ArrayLike) -> FloatArray:
    """(...x4, XYZW) -> (...x4, WXYZ)."""
    q = np.asarray(quat)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def quat_wxyz_to_matrix(quat: ArrayLike) -> FloatArray:
    """Unit quaternion (...x4, WXYZ; normalised here) -> rotation matrix (...x3x3)."""
    q = np.asarray(quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quat_wxyz(rotation: ArrayLike) -> FloatArray:
    """Rotation matrix (...x3x3) -> unit quaternion (...x4, WXYZ) with w >= 0.

    Uses the numerically stable branch on the largest of (w, x, y, z) (Shepperd's method).
    """
    r = np.asarray(rotation, dtype=np.float64)
    batch = r.shape[:-2]
    r = r.reshape(-1, 3, 3)
    m00, m11, m22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    # 4*q_i^2 for i in (w, x, y, z); the largest one is the safe pivot.
    sq = np.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    pivot = np.argmax(sq, axis=-1)
    rows = np.arange(len(r))
    s = 2.0 * np.sqrt(np.maximum(sq[rows, pivot], 1e-300))
    # Each pivot's (w, x, y, z) times s (the pivot's own component: s / 4 = (s * s / 4) / s),
    # built for all four pivots at once and picked per matrix: one pass of numpy calls however
    # many matrices (the per-call cost dominated a single matrix's conversion).
    d21, d02, d10 = r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]
    s01, s02, s12 = r[:, 0, 1] + r[:, 1, 0], r[:, 0, 2] + r[:, 2, 0], r[:, 1, 2] + r[:, 2, 1]
    own = s * s / 4
    scaled = np.stack(
        [
            np.stack([own, d21, d02, d10], axis=-1),
            np.stack([d21, own, s01, s02], axis=-1),
            np.stack([d02, s01, own, s12], axis=-1),
            np.stack([d10, s02, s12, own], axis=-1),
        ],
        axis=1,
    )  # (n, pivot, 4)
    q = scaled[rows, pivot] / s[:, None]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(*batch, 4)


def rigid_from_rotation_translation(rotation: ArrayLike, translation: ArrayLike) -> FloatArray:
    """Rotation (...x3x3) and translation (...x3) -> homogeneous pose (...x4x4)."""
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    batch = np.broadcast_shapes(r.shape[:-2], t.shape[:-1])
    pose = np.zeros((*batch, 4, 4))
    pose[..., :3, :3] = r
    pose[..., :3, 3] = t
    pose[..., 3, 3] = 1.0
    return pose


def invert_rigid(pose: ArrayLike) -> FloatArray:
    """Inverse of a rigid pose (...x4x4): T_b_from_a -> T_a_from_b, using R^T (no general inverse)."""
    p = np.asarray(pose, dtype=np.float64)
    r_t = np.swapaxes(p[..., :3, :3], -1, -2)
    return rigid_from_rotation_translation(r_t, -np.einsum("...ij,...j->...i", r_t, p[..., :3, 3]))


def apply_rigid(pose: ArrayLike, points: ArrayLike) -> FloatArray:
    """Apply pose (...x4x4, T_a_from_b) to points (...xNx3, in b) -> points (...xNx3, in a)."""
    p = np.asarray(pose)
    x = np.asarray(points)
    return np.einsum("...ij,...nj->...ni", p[..., :3, :3], x) + p[..., None, :3, 3]


def rotation_angle_deg(rotation: ArrayLike) -> FloatArray:
    """Geodesic angle of a rotation (...x3x3) from the identity, in degrees, in [0, 180]."""
    r = np.asarray(rotation, dtype=np.float64)
    cos = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def rotation_error_deg(rotation_a: ArrayLike, rotation_b: ArrayLike) -> FloatArray:
    """Geodesic angle between two rotations (...x3x3 each), in degrees: angle(R_a^T R_b)."""
    a = np.asarray(rotation_a, dtype=np.float64)
    b = np.asarray(rotation_b, dtype=np.float64)
    return rotation_angle_deg(np.swapaxes(a, -1, -2) @ b)


def random_rotation(rng: np.random.Generator, size: int | None = None) -> FloatArray:
    """Rotations drawn uniformly from SO(3) (normalised Gaussian quaternions): (3x3) or (size x3x3)."""
    q = rng.normal(size=(1 if size is None else size, 4))
    r = quat_wxyz_to_matrix(q)
    return r[0] if size is None else r


def axis_angle_to_matrix(axis: ArrayLike, angle_rad: ArrayLike) -> FloatArray:
    """Rotation of ``angle_rad`` (...) about ``axis`` (...x3, normalised here) -> (...x3x3)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    half = np.asarray(angle_rad, dtype=np.float64)[..., None] / 2.0
    return quat_wxyz_to_matrix(np.concatenate([np.cos(half), np.sin(half) * a], axis=-1))


def viewing_axis_turns(count: int) -> FloatArray:
    """``count`` starting rotations (count x3x3) for IT-Net runs on one cloud: turns about z
    (a camera's viewing axis) 360/count degrees apart from the identity. A turn about the
    viewing axis keeps a view one the network was trained on, from a different place."""
    angles = 2 * np.pi * np.arange(count) / count
    return np.asarray(axis_angle_to_matrix([0.0, 0.0, 1.0], angles)).reshape(count, 3, 3)
