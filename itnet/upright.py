"""Poses held upright: where the caller knows which way is up in its cloud (gravity from an IMU,
a floor or table plane), the canonical frame's +y is that direction and only the turn about it
(yaw) and the position are left to estimate.

Pure numpy. The service starts a request's runs from ``upright_starts`` (yaw turns of the
rotation that stands the cloud up) and, after every network step, stands each run's pose back
up with ``held_upright``: the least rotation of the canonical frame that brings the given up
onto +y, about the canonical origin, so the object's estimated centre does not move. The
network then only has the yaw to get right; the tilts a partial view leaves ambiguous (a box on
its side, a monitor face up) are ruled out.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from itnet.geometry import FloatArray, axis_angle_to_matrix

UP = np.array([0.0, 1.0, 0.0])
UPRIGHT_EVAL_DEG = 2.0  # the up direction's error in upright validation and test views


def unit_up(up: ArrayLike) -> FloatArray:
    """A direction (3,) -> its unit vector; ValueError unless it is three finite numbers, not
    all zero."""
    v = np.asarray(up, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError("up must be three finite numbers: the up direction's x, y, z")
    norm = float(np.linalg.norm(v))
    if norm < 1e-9:
        raise ValueError("up must not be the zero vector")
    return v / norm


def rotation_onto(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """The least rotations (...x3x3) taking unit vectors ``a`` (...x3) onto unit ``b`` (...x3 or
    3,): about ``a x b``; a half turn about an axis normal to ``a`` where they are opposite."""
    a = np.asarray(a, dtype=np.float64)
    b = np.broadcast_to(np.asarray(b, dtype=np.float64), a.shape)
    axis = np.cross(a, b)
    sin = np.linalg.norm(axis, axis=-1)
    cos = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    # where a and b are (anti)parallel the cross product has no direction: any axis normal to a
    other = np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    normal = np.cross(a, other)
    axis = np.where(sin[..., None] > 1e-9, axis, normal)
    return axis_angle_to_matrix(axis, np.arctan2(sin, cos))


def held_upright(poses: ArrayLike, up: ArrayLike) -> FloatArray:
    """Poses T_canonical_from_input (...x4x4) -> the same poses turned about the canonical origin
    (left-multiplied by a rotation) so that each takes the input's ``up`` (3,, unit) onto +y;
    the object's centre in the input frame, ``-R^T t``, is unchanged."""
    t = np.asarray(poses, dtype=np.float64)
    lifted = np.einsum("...ij,j->...i", t[..., :3, :3], np.asarray(up, dtype=np.float64))
    out = t.copy()
    out[..., :3, :] = _onto_up(lifted) @ t[..., :3, :]
    return out


def _onto_up(a: FloatArray) -> FloatArray:
    """``rotation_onto(a, UP)`` for directions ``a`` (...x3, unit to rounding: a network's
    rotation applied to up), in closed form (Rodrigues on a normalised: I + K + K² / (1 + a·y),
    K the cross-product matrix of a x y): what every step of a run held upright pays, a fifth of
    the general path's time. Where ``a`` points more than about 84° away from +y, the general
    path: toward -y, 1 + a·y goes to 0 and the closed form's precision with it."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([np.stack([zero, -x, zero], -1), np.stack([x, zero, z], -1),
                  np.stack([zero, -z, zero], -1)], -2)  # fmt: skip
    far = y < 0.1
    scale = 1.0 / np.where(far, 1.0, 1.0 + y)
    out = np.eye(3) + k + (k @ k) * scale[..., None, None]
    if np.any(far):
        out[far] = rotation_onto(a[far], UP)
    return out


def upright_starts(up: ArrayLike, count: int) -> FloatArray:
    """``count`` starting rotations (count x3x3) that take ``up`` (3,, unit) onto +y, turned
    about +y 360/count degrees apart (the first: the least rotation alone)."""
    stand = rotation_onto(np.asarray(up, dtype=np.float64), UP)
    yaws = axis_angle_to_matrix(UP, 2 * np.pi * np.arange(count) / count)
    return yaws @ stand


def tilted(ups: ArrayLike, error_deg: ArrayLike, rng: np.random.Generator) -> FloatArray:
    """Unit directions (S, 3) -> each turned by ``error_deg`` (scalar or (S,)) about a random
    axis normal to it: an up direction as a gravity sensor with that error would give it."""
    ups = np.asarray(ups, dtype=np.float64)
    angles = np.broadcast_to(np.radians(np.asarray(error_deg, dtype=np.float64)), ups.shape[:1])
    axes = np.cross(ups, rng.normal(size=ups.shape))  # normal to each up
    return np.einsum("sij,sj->si", axis_angle_to_matrix(axes, angles), ups)


def sensed_ups(poses: ArrayLike, error_deg: float, rng: np.random.Generator) -> FloatArray:
    """Scans' poses T_canonical_from_input (S, 4, 4) -> each scan's up direction in its own
    frame (the canonical +y taken back, ``R^T e_y``) as a gravity sensor with ``error_deg`` of
    error gives it (:func:`tilted`; 0: the truth, ``rng`` untouched) -> (S, 3) unit vectors."""
    truth = np.asarray(poses, dtype=np.float64)[:, 1, :3]  # row 1 of R: R^T e_y
    return truth if error_deg == 0 else tilted(truth, error_deg, rng)


def levelled(points: ArrayLike, up: ArrayLike) -> FloatArray:
    """A cloud (N, 3) and its up direction (3,, unit) -> the cloud turned about its origin by
    the least rotation that takes ``up`` onto +y: the object stands, its yaw is left as it was."""
    stand = rotation_onto(np.asarray(up, dtype=np.float64), UP)
    return np.asarray(points, dtype=np.float64) @ stand.T
