"""Robust fusion of several pose estimates of one cloud (the ensemble mode's answer).

Pure numpy. K runs of IT-Net on one cloud (from different starts, on different random subsets)
mostly agree, and the ones that went to another basin disagree wildly; the mean of all of them
would be pulled off by those.
So the fused pose is:

1. the medoid: the run whose rotation is closest (summed geodesic angle) to all the others, where
   two rotations that differ by a turn of the category's symmetry (``itnet.symmetry``) count as
   the same;
2. every run's rotation turned by the symmetry element that brings it nearest the medoid;
3. the inliers: runs within ``inlier_deg`` of the medoid;
4. their chordal mean rotation (the sum of the matrices projected back onto SO(3)) and the mean of
   their object centres (the centre, ``inv(T)``'s translation, does not depend on the turn).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from itnet.geometry import FloatArray, rotation_error_deg
from itnet.symmetry import symmetry_group

INLIER_DEG = 20.0
FUSION_YAW_SAMPLES = 72  # 5 degrees apart: plenty to pick a round object's representative


def nearest_rotation(matrix: ArrayLike) -> FloatArray:
    """The rotation (3x3) nearest a 3x3 matrix in the Frobenius norm (SVD, det +1)."""
    u, _, vt = np.linalg.svd(np.asarray(matrix, dtype=np.float64))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def fuse_poses(
    poses: ArrayLike,
    symmetry: str = "none",
    inlier_deg: float = INLIER_DEG,
    anchor: int | None = None,
) -> FloatArray:
    """Poses T_canonical_from_input (K, 4, 4) of one cloud -> one fused pose (4, 4) (see module).
    ``anchor``: that run stands in for the medoid (step 1), e.g. the run that sits most firmly in
    its basin (``itnet.basin``)."""
    t = np.asarray(poses, dtype=np.float64)
    if len(t) == 1:
        return t[0].copy()
    rotations = t[:, :3, :3]
    centres = -np.einsum("kji,kj->ki", rotations, t[:, :3, 3])  # -R^T t: the object's centre
    turned, angles = _pairwise(rotations, symmetry)
    closest = angles.min(axis=2)
    medoid = int(np.argmin(closest.sum(axis=1))) if anchor is None else int(anchor)
    best_turn = angles[medoid].argmin(axis=1)  # (K,): the element bringing each run nearest
    aligned = turned[np.arange(len(t)), best_turn]  # (K, 3, 3)
    inliers = closest[medoid] < inlier_deg
    fused = np.eye(4)
    fused[:3, :3] = nearest_rotation(aligned[inliers].sum(axis=0))
    fused[:3, 3] = -fused[:3, :3] @ centres[inliers].mean(axis=0)
    return fused


def medoid_index(poses: ArrayLike, symmetry: str = "none") -> int:
    """Poses (K, 4, 4) -> the run ``fuse_poses`` centres its fusion on (step 1 above)."""
    rotations = np.asarray(poses, dtype=np.float64)[:, :3, :3]
    return int(np.argmin(_pairwise(rotations, symmetry)[1].min(axis=2).sum(axis=1)))


def _pairwise(rotations: FloatArray, symmetry: str) -> tuple[FloatArray, FloatArray]:
    """Rotations (K, 3, 3) -> (every rotation turned by every element of the symmetry group,
    S_g R_j (K, G, 3, 3); angle[i, j, g] between rotation i and S_g R_j (K, K, G), degrees)."""
    group = symmetry_group(symmetry, FUSION_YAW_SAMPLES)  # (G, 3, 3)
    turned = group[None] @ rotations[:, None]
    return turned, rotation_error_deg(rotations[:, None, None], turned[None])
