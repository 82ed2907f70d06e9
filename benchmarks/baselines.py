"""Registration baselines for ``bench_align``: each maps (cloud A (N, 3), cloud B (M, 3)) to
T_b_from_a (4x4). Every size is a fraction of B's RMS radius about its centroid (what a user
could measure; never the ground truth), so the methods see the same information as itnet-align.

Global methods (FPFH + RANSAC, FGR, KISS-Matcher) are followed by the same point-to-plane ICP as
``itnet-align --refine`` (``itnet.alignment.refine.IcpRefiner``), so the comparison is about the global step.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from itnet.alignment.refine import IcpRefiner
from itnet.preprocess import estimate_normalization

Method = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]
VOXEL = 0.1  # downsampling for features, as a fraction of B's RMS radius
ICP_DISTANCE = 0.1  # the final ICP correspondence distance, as in itnet-align --refine


def _scale(points: NDArray) -> float:
    return estimate_normalization(points).scale


def _features(points: NDArray, voxel: float):  # type: ignore[no-untyped-def]
    """Voxel-downsampled open3d cloud with normals, and its FPFH features."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud = cloud.voxel_down_sample(voxel)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    )
    return cloud, fpfh


def _then_icp(a: NDArray, b: NDArray, start: NDArray) -> NDArray[np.float64]:
    return IcpRefiner(a, b, ICP_DISTANCE * _scale(b)).refine(start).T_b_from_a


def fpfh_ransac_icp(a: NDArray, b: NDArray, seed: int = 0) -> NDArray[np.float64]:
    """Open3D's global registration recipe: FPFH features, RANSAC on feature matches, then ICP."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    voxel = VOXEL * _scale(b)
    (src, f_src), (dst, f_dst) = _features(a, voxel), _features(b, voxel)
    result = reg.registration_ransac_based_on_feature_matching(
        src, dst, f_src, f_dst, True, 1.5 * voxel,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
         reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(100_000, 0.999),
    )  # fmt: skip
    return _then_icp(a, b, np.asarray(result.transformation))


def fgr_icp(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """Open3D's Fast Global Registration on FPFH matches, then ICP."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    voxel = VOXEL * _scale(b)
    (src, f_src), (dst, f_dst) = _features(a, voxel), _features(b, voxel)
    option = reg.FastGlobalRegistrationOption(maximum_correspondence_distance=1.5 * voxel)
    result = reg.registration_fgr_based_on_feature_matching(src, dst, f_src, f_dst, option)
    return _then_icp(a, b, np.asarray(result.transformation))


def kiss_matcher_icp(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """KISS-Matcher (faster-PFH matching, graph pruning, robust solver), then ICP."""
    import kiss_matcher

    config = kiss_matcher.KISSMatcherConfig(voxel_size=VOXEL * _scale(b))
    solution = kiss_matcher.KISSMatcher(config).estimate(a.astype(np.float32), b.astype(np.float32))
    start = np.eye(4)
    if solution.valid:
        start[:3, :3], start[:3, 3] = (
            np.asarray(solution.rotation),
            np.asarray(solution.translation),
        )
    return _then_icp(a, b, start)


def small_gicp_identity(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """small_gicp's GICP from the identity (a local method: it needs a close start)."""
    import small_gicp

    scale = _scale(b)
    result = small_gicp.align(b, a, registration_type="GICP", downsampling_resolution=0.05 * scale,
                              max_correspondence_distance=0.5 * scale, num_threads=1)  # fmt: skip
    return np.asarray(result.T_target_source, dtype=np.float64)


def icp_identity(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """Open3D point-to-plane ICP from the identity, with a wide first stage (0.5 then 0.25 x RMS
    radius): what ICP alone does when the two sensor frames are not related."""
    return IcpRefiner(a, b, 0.25 * _scale(b)).refine(np.eye(4)).T_b_from_a


def available() -> dict[str, Method]:
    """The baselines whose packages import here, by display name."""
    methods: dict[str, Method] = {}
    try:
        import open3d  # noqa: F401

        methods["FPFH+RANSAC+ICP (Open3D)"] = fpfh_ransac_icp
        methods["FGR+ICP (Open3D)"] = fgr_icp
        methods["ICP from identity (Open3D)"] = icp_identity
    except ImportError:
        pass
    try:
        import kiss_matcher  # noqa: F401

        methods["KISS-Matcher+ICP"] = kiss_matcher_icp
    except ImportError:
        pass
    try:
        import small_gicp  # noqa: F401

        methods["small_gicp GICP from identity"] = small_gicp_identity
    except ImportError:
        pass
    return methods
