"""Point sets seen as surfaces: each point a small oriented disc (a surfel), z-buffered exactly.

A 1,024-point shape leaves most pixels of a depth image empty, so a z-buffer of its points lets
far surfaces show through a near one (the paper's views). A depth camera looks at a surface. Here
each point becomes a disc: its normal from the PCA of its nearest neighbours, its radius a
multiple of the local spacing. Every disc is intersected with the rays through the pixel centres
it can reach (perspective, exact: a ray ``t·(u, v, 1)`` meets the plane ``n·(q − p) = 0`` at
``t = n·p / n·(u, v, 1)``), the nearest hit per pixel is the depth image, and a point is seen when
its own disc is within ``tolerance`` of that depth at its pixel. Near surfaces then hide far ones
as a mesh would, and sloped surfaces do not hide themselves (each disc lies in its surface).

Pure numpy; the discs of a shape are computed once (``surface_discs``) and reused for every view.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

MAX_PIXEL_REACH = 6  # pixels a disc may cover from its centre's pixel, each way (memory bound)


def surface_discs(
    points: NDArray, neighbours: int = 8, cells: int = 4_000_000
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points (M, 3) -> (unit normals (M, 3), local spacing (M,)).

    The normal is the least-variance direction of the point and its ``neighbours`` nearest
    neighbours (sign arbitrary: the z-buffer does not need it); the spacing is the mean distance
    to those neighbours. Brute-force neighbours, a block of rows at a time with at most
    ``cells`` distances in memory (32 MB by default).
    """
    p = np.asarray(points, dtype=np.float64)
    k = min(neighbours, len(p) - 1)
    if k < 2:
        raise ValueError(f"need at least 3 points for surface discs, got {len(p)}")
    normals, spacing = np.empty_like(p), np.empty(len(p))
    sq = (p * p).sum(1)
    block = max(1, cells // len(p))
    for start in range(0, len(p), block):
        rows = slice(start, start + block)
        d2 = np.maximum(sq[rows, None] + sq[None, :] - 2 * p[rows] @ p.T, 0.0)
        near = np.argpartition(d2, k, axis=1)[:, : k + 1]  # the point itself and k neighbours
        patch = p[near] - p[near].mean(1, keepdims=True)
        _, vectors = np.linalg.eigh(np.einsum("mki,mkj->mij", patch, patch))
        normals[rows] = vectors[:, :, 0]
        spacing[rows] = np.sqrt(np.take_along_axis(d2, near, 1)).sum(1) / k
    return normals, spacing


def splat_visible(
    camera_points: NDArray,
    camera_normals: NDArray,
    radii: NDArray,
    pixel: float,
    tolerance: float,
) -> NDArray[np.bool_]:
    """Visibility mask (M,) of camera-frame surfels: centres (M, 3) with z > 0, unit normals
    (M, 3) in the camera frame, radii (M,), under a pinhole camera whose pixel is ``pixel`` wide
    at the median depth (see the module doc)."""
    p, n, r = camera_points, camera_normals, np.asarray(radii, dtype=np.float64)
    z = p[:, 2]
    angular = pixel / np.median(z)  # tan of one pixel's angle
    s = p[:, :2] / z[:, None] / angular  # continuous pixel coordinates
    own = np.floor(s).astype(np.int64)
    reach = np.minimum(np.ceil(r / (angular * z)).astype(np.int64), MAX_PIXEL_REACH)
    span = np.arange(-reach.max(), reach.max() + 1)
    du, dv = (o.ravel() for o in np.meshgrid(span, span, indexing="ij"))
    offsets_of = (np.abs(du)[None] <= reach[:, None]) & (np.abs(dv)[None] <= reach[:, None])
    point, k = np.nonzero(offsets_of)  # candidate (disc, pixel) pairs
    pix = own[point] + np.stack([du[k], dv[k]], 1)
    hit_depth = _disc_hits(p[point], n[point], r[point], pix, angular)
    ok = np.isfinite(hit_depth)
    lo = pix.min(0)
    shape = pix.max(0) - lo + 1
    flat = np.ravel_multi_index((pix - lo).T, shape)
    depth = np.full(int(np.prod(shape)), np.inf)
    np.minimum.at(depth, flat[ok], hit_depth[ok])
    own_depth = _disc_hits(p, n, np.full(len(p), np.inf), own, angular)  # its plane, unbounded
    own_depth = np.where(np.isfinite(own_depth), own_depth, z)  # edge-on: its own depth
    own_flat = np.ravel_multi_index((own - lo).T, shape)
    return own_depth <= np.minimum(depth[own_flat], own_depth) + tolerance


def _disc_hits(
    centres: NDArray, normals: NDArray, radii: NDArray, pixels: NDArray, angular: float
) -> NDArray[np.float64]:
    """Depth (K,) at which the ray through each pixel centre (K, 2) meets its disc (K,), or inf
    where it misses (outside the radius, parallel, or behind the camera)."""
    rays = np.concatenate([(pixels + 0.5) * angular, np.ones((len(pixels), 1))], 1)
    facing = np.einsum("ij,ij->i", normals, rays)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", normals, centres) / facing
    hit = t[:, None] * rays
    inside = (np.abs(facing) > 1e-9) & (t > 0) & (((hit - centres) ** 2).sum(1) <= radii**2)
    return np.where(inside, t, np.inf)
