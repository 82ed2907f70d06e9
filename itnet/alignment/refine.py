"""ICP refinement of an alignment with open3d (point-to-plane), for ``itnet-align --refine``.

open3d is the optional extra ``refine`` (``pip install itnet[refine]``): it is imported inside
the functions, so the rest of itnet works without it, and ``RefineUnavailable`` says how to get it.

Frames: ``source`` is cloud A (N, 3), ``target`` is cloud B (M, 3); every transform is
T_target_from_source = T_b_from_a (4x4, B's units).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


class RefineUnavailable(RuntimeError):
    """open3d is not installed."""


@dataclass(frozen=True)
class RefineResult:
    """A refined T_b_from_a (4x4) and open3d's own measures at the last stage's distance:
    fitness = share of A's points with a B point within it, rmse = RMS distance of those pairs."""

    T_b_from_a: NDArray[np.float64]
    fitness: float
    rmse: float


def require_open3d() -> None:
    """Import open3d now (about half a second), or raise RefineUnavailable saying how to get it."""
    _open3d()


def refine_wanted(asked: bool | None, note: Callable[[str], None] | None = None) -> bool:
    """Whether an alignment refines with ICP: ``asked`` False: no; True: yes, RefineUnavailable
    where open3d is absent; None (the default): where open3d imports (imported now, so that no
    request's time pays for it), else no, with the reason told to ``note``."""
    if asked is False:
        return False
    try:
        require_open3d()
    except RefineUnavailable as err:
        if asked:
            raise
        if note is not None:
            note(str(err))
        return False
    return True


def _open3d() -> Any:
    try:
        import open3d as o3d
    except ImportError as err:  # also raised when libusb-1.0 is missing
        raise RefineUnavailable(
            f"ICP refinement needs open3d: pip install 'itnet[refine]' ({err})"
        ) from None
    return o3d


def _prepared(points: ArrayLike, voxel: float, normal_radius: float | None = None) -> Any:
    """An open3d cloud, voxel-downsampled when ``voxel`` > 0, with normals when a
    ``normal_radius`` is given (point-to-plane needs them on the target only)."""
    o3d = _open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    if voxel > 0:
        cloud = cloud.voxel_down_sample(voxel)
    if normal_radius is not None:
        search = o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=30)
        cloud.estimate_normals(search)
    return cloud


class IcpRefiner:
    """Point-to-plane ICP of A onto B, prepared once (downsampling, normals) for many starts.

    ``max_distance`` (B's units) is the correspondence cut-off of the final stage; a first stage
    runs at twice that distance to pull in estimates that are further off. A Tukey kernel at the
    stage's distance keeps the points of A that B never saw from dragging the pose. A stage
    stops after ``iterations`` or once fitness and RMSE change by less than ``tolerance``
    (relative): open3d's default, 1e-6, runs nearly every iteration for no better answer.
    """

    def __init__(
        self,
        source: ArrayLike,
        target: ArrayLike,
        max_distance: float,
        voxel: float = 0.0,
        iterations: int = 30,
        tolerance: float = 1e-4,
        coarse_points: int | None = None,
    ) -> None:
        if max_distance <= 0:
            raise ValueError(f"max_distance must be positive, got {max_distance}")
        self.source = _prepared(source, voxel)
        # The coarse stage only has to bring a start within the fine stage's reach: on a seeded
        # subset of ``coarse_points`` of A's points (None: all) it costs less for the same.
        self.coarse_source = self.source
        count = len(self.source.points)
        if coarse_points is not None and count > coarse_points:
            keep = np.random.default_rng(0).choice(count, coarse_points, replace=False)
            self.coarse_source = self.source.select_by_index(np.sort(keep).tolist())
        self.target = _prepared(target, voxel, 2.0 * max_distance)
        self.stages = (2.0 * max_distance, max_distance)
        self.iterations, self.tolerance = iterations, tolerance

    def refine(self, b_from_a: ArrayLike, stages: slice = slice(None)) -> RefineResult:
        """Start at T_b_from_a (4x4) -> the refined one, with fitness and rmse. ``stages``: run
        only these of ``self.stages`` (e.g. ``slice(1)`` for the coarse one, ``slice(1, None)``
        to finish from it)."""
        reg = _open3d().pipelines.registration
        pose = np.asarray(b_from_a, dtype=np.float64).copy()
        result = None
        for stage in range(len(self.stages))[stages]:
            distance = self.stages[stage]
            source = self.coarse_source if stage == 0 else self.source
            method = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=distance))
            criteria = reg.ICPConvergenceCriteria(self.tolerance, self.tolerance, self.iterations)
            result = reg.registration_icp(source, self.target, distance, pose, method, criteria)
            pose = np.asarray(result.transformation, dtype=np.float64).copy()
        assert result is not None
        return RefineResult(pose, float(result.fitness), float(result.inlier_rmse))


def icp_point_to_plane(
    source: ArrayLike,
    target: ArrayLike,
    b_from_a: ArrayLike,
    max_distance: float,
    voxel: float = 0.0,
    iterations: int = 30,
) -> RefineResult:
    """One ICP run: A (N, 3) onto B (M, 3) from T_b_from_a (4x4); see ``IcpRefiner``."""
    return IcpRefiner(source, target, max_distance, voxel, iterations).refine(b_from_a)
