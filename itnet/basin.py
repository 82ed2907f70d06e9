"""How firmly each of K runs on one cloud sits in its basin: a verifier for the ensemble mode.

Pure numpy around a step function. Of the paper views of the chair that K = 8 fused runs miss,
about half have a right run among the eight (docs/ensemble.md): the fusion's medoid follows the
majority, and a wrong basin can hold the majority. A right pose is a strong attractor of the
network; a wrong one often is not. So each run's final pose is knocked off by a few fixed turns
(``probe_turns``), the network takes a few steps from each, and the run's *drift* is how far,
on average, those steps end from where the run was. Where the fusion's medoid drifts more than
``UNSURE_DEG`` (the majority does not hold its pose), the run that drifts least anchors the
fusion instead (``firm_anchor``, ``fusion.fuse_poses(anchor=...)``); a medoid that holds keeps
its place, and with it the majority's mean.

Where the category has a learned verifier (``model/verifier.py``: a PointNet trained on the
pose model's own runs on training shapes to tell a right pose from a wrong one by how the
cloud looks where the pose puts it), its scores replace the probes: each run's points are put
where its pose says (``canonical_points``), one forward pass scores them all, and the likeliest
run anchors the fusion (``likeliest_run``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from itnet.geometry import FloatArray, axis_angle_to_matrix, rotation_error_deg

# A step of the network: (points (B, N, 3), poses (B, 4, 4)) -> the next poses (B, 4, 4)
Step = Callable[[NDArray[np.float32], NDArray[np.float32]], NDArray[np.float32]]
PROBE_DEG = 30.0  # how far each probe knocks a run's pose off
PROBE_STEPS = 5  # the network's steps back from each probe
UNSURE_DEG = 10.0  # a medoid drifting more than this gives way to the firmest run
TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64)


def probe_turns(angle_deg: float, axes: NDArray = TETRAHEDRON) -> FloatArray:
    """Turns (J, 4, 4) of ``angle_deg`` about fixed axes (J, 3) (by default the four that point
    to a tetrahedron's corners: no direction favoured)."""
    turns = np.tile(np.eye(4), (len(axes), 1, 1))
    turns[:, :3, :3] = axis_angle_to_matrix(axes, np.full(len(axes), np.radians(angle_deg)))
    return turns


def basin_drift(
    step: Step, points: NDArray, poses: NDArray, turns: NDArray, steps: int
) -> FloatArray:
    """K runs' inputs (K, N, 3) and final poses T (K, 4, 4), normalised frame -> each run's drift
    (K,), degrees: each pose turned by every probe ``turns`` (J, 4, 4) in the canonical frame
    (S T), ``steps`` steps of ``step`` from there on the run's own points (one batch of K J),
    and the mean angle between where they end and T."""
    k, j = len(poses), len(turns)
    starts = (turns[None].astype(np.float64) @ poses[:, None].astype(np.float64)).reshape(
        k * j, 4, 4
    )
    x = np.repeat(points, j, axis=0).astype(np.float32)
    moved = starts.astype(np.float32)
    for _ in range(steps):
        moved = step(x, moved)
    ends = moved.reshape(k, j, 4, 4)[..., :3, :3].astype(np.float64)
    return rotation_error_deg(ends, poses[:, None, :3, :3].astype(np.float64)).mean(axis=1)


def firm_anchor(drift: NDArray, medoid: int, unsure_deg: float = UNSURE_DEG) -> int:
    """Each run's drift (K,) and the fusion's medoid -> the run to anchor the fusion on: the
    medoid while it holds (drift at most ``unsure_deg``), else the run that drifts least."""
    return medoid if drift[medoid] <= unsure_deg else int(np.argmin(drift))


def canonical_points(points: NDArray, poses: NDArray) -> NDArray[np.float32]:
    """K runs' points (K, N, 3) and poses T (K, 4, 4), normalised frame -> each run's points
    where its pose puts them, T p (K, N, 3): what a learned verifier judges."""
    rotations, shifts = poses[:, :3, :3], poses[:, None, :3, 3]
    return (points @ rotations.transpose(0, 2, 1) + shifts).astype(np.float32)


def likeliest_run(scores: NDArray) -> int:
    """A learned verifier's scores (K,), one a run (the logit of its pose being right) -> the run
    to anchor the fusion on: the one it finds likeliest."""
    return int(np.argmax(scores))
