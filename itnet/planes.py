"""Planes of a scene or a cut-out: the floor (which way is up) and the walls, by RANSAC.

Numpy (and scipy's KD-tree for neighbouring points). A plane is ``n·p + d = 0`` with ``n`` a
unit normal; the floor's normal is oriented toward the camera (the camera stands above the
floor), so ``n·p + d`` is a point's height. Hypotheses are drawn many at once, from points
anywhere or near each other, and scored on a random sample of the cloud, the best one refined
by a least-squares fit to its inliers in the whole cloud. A prior direction restricts
the hypotheses: the floor's normal lies within ``max_tilt_deg`` of the expected up (a camera
with its image's y down, held about level: −y), a wall's is horizontal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from itnet.columns import column_mean


@dataclass(frozen=True)
class Plane:
    """``normal`` (3,) unit, ``offset`` d: the plane is ``normal·p + offset = 0``."""

    normal: NDArray[np.float64]
    offset: float

    def distance(self, points: NDArray) -> NDArray[np.float64]:
        """Points (N, 3) -> signed distances (N,) along the normal."""
        return np.asarray(points, dtype=np.float64) @ self.normal + self.offset

    def toward(self, direction: NDArray) -> Plane:
        """The same plane with its normal on ``direction``'s (3,) side."""
        return self if self.normal @ direction >= 0 else Plane(-self.normal, -self.offset)


def floor_axes(up: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A unit up (3,) -> two unit directions (3,) along the floor, normal to it and to each
    other."""
    across = _cross(up, (1.0, 0.0, 0.0) if abs(up[0]) < 0.9 else (0.0, 0.0, 1.0))
    across /= np.linalg.norm(across)
    return across, _cross(up, across)


def _cross(a: NDArray, b: NDArray | tuple[float, float, float]) -> NDArray[np.float64]:
    """``np.cross`` of two 3-vectors, the same numbers, without its general machinery (a
    scene's segmentation takes a few hundred: 15 us each against 2)."""
    a0, a1, a2 = (float(v) for v in a)
    b0, b1, b2 = (float(v) for v in b)
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def fit_plane(points: NDArray) -> Plane:
    """Least-squares plane through points (N >= 3, 3): through their centroid, normal to the
    direction of least variance."""
    centre = column_mean(points)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[2]
    return Plane(normal, float(-normal @ centre))


def ransac_plane(
    points: NDArray,
    rng: np.random.Generator,
    threshold: float,
    accept: Callable[[NDArray], NDArray],
    hypotheses: int = 200,
    sample: int = 2000,
    refine: int = 20000,
    beyond_m: float | None = None,
    local: int = 0,
    neighbours: int = 16,
    toward: NDArray | None = None,
) -> tuple[Plane, NDArray[np.bool_]] | None:
    """The plane with most points within ``threshold`` among ``hypotheses`` random triples
    whose normals (K, 3) ``accept`` keeps (K,) bool, counted on ``sample`` random points, then
    refined twice by ``fit_plane`` on its inliers among ``refine`` random points -> (plane,
    inlier mask (N,)), or None when no hypothesis is kept. With ``beyond_m``, each point
    farther than that beyond a hypothesis, on its side away from the origin (the camera; with
    ``toward`` (3,), on its side away from that direction: up, for a cloud with no camera at
    its origin), counts against it: nothing is seen below a floor, while a plane through a seat
    or a tub's rim has the floor and the objects' lower parts below it. ``local`` of the
    hypotheses take their second and third points among the first's ``neighbours`` nearest
    in the sample: a plane that is a small part of the view (a floor seen past the objects
    before it) is then still drawn often, where three points drawn anywhere rarely all lie
    on it."""
    if len(points) < 3:
        return None
    scored = points[rng.integers(0, len(points), size=min(sample, len(points)))]
    triples = scored[rng.integers(0, len(scored), size=(hypotheses, 3))]
    local = min(local, hypotheses)
    if local and len(scored) > neighbours:
        first = rng.integers(0, len(scored), size=local)
        _, near = cKDTree(scored).query(scored[first], k=neighbours + 1)
        pick = near[np.arange(local)[:, None], rng.integers(1, neighbours + 1, size=(local, 2))]
        triples[:local] = scored[np.c_[first, pick]]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / np.maximum(length, 1e-12)
    kept = (length[:, 0] > 1e-9) & np.asarray(accept(normals), dtype=bool)
    if not kept.any():
        return None
    normals, anchors = normals[kept], triples[kept, 0]
    offsets = -np.einsum("kj,kj->k", normals, anchors)
    if beyond_m is not None:  # the origin (or ``toward``) on each plane's positive side
        facing = offsets if toward is None else normals @ np.asarray(toward, dtype=np.float64)
        side = np.where(facing < 0, -1.0, 1.0)
        normals, offsets = normals * side[:, None], offsets * side
    # (S, K) distances in float32: the sample's points to every hypothesis
    signed = scored.astype(np.float32) @ normals.T.astype(np.float32) + offsets.astype(np.float32)
    counts = (np.abs(signed) < threshold).sum(axis=0)
    if beyond_m is not None:
        counts = counts - (signed < -beyond_m).sum(axis=0)
    best = int(np.argmax(counts))
    plane = refined_plane(
        Plane(normals[best], float(offsets[best])), points, threshold, rng, refine
    )
    if plane is None:
        return None
    return plane, np.abs(plane.distance(points)) < threshold


def refined_plane(
    plane: Plane, points: NDArray, threshold: float, rng: np.random.Generator, sample: int = 20000
) -> Plane | None:
    """``plane`` refitted twice by ``fit_plane`` to its inliers within ``threshold`` among a
    random ``sample`` of the points (N, 3), its normal kept on the same side (the fit's sign is
    arbitrary); None where fewer than 3 points lie that near it."""
    fitted = points if len(points) <= sample else points[rng.integers(0, len(points), size=sample)]
    for _ in range(2):
        inliers = np.abs(plane.distance(fitted)) < threshold
        if inliers.sum() < 3:
            return None
        refit = fit_plane(fitted[inliers])
        plane = refit if refit.normal @ plane.normal >= 0 else Plane(-refit.normal, -refit.offset)
    return plane
