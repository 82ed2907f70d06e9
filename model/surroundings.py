"""What a box cut out of a room keeps beside its object: floor, wall and a neighbour's side.

A real object is never scanned alone. Cut out of a depth frame by its box, or by a segmenter
that removed the floor and the walls as planes, it keeps a strip of the floor it stands on (a
user's box grown a little below its base; a segmenter's plane removal leaves the floor's noisy
top), a strip of the wall it stands against (night stands, dressers and beds stand there), and
a piece of whatever stands beside it (a bed beside a night stand, a table beside a chair).

``Surroundings.around`` adds such surfaces, as points, around a canonical shape (object radii,
+y up) before it is scanned, so that the scanner's z-buffer hides what the object hides and the
sensor model treats them as it treats the object; ``Surroundings.crop`` then keeps what the
object's box, grown, holds. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Surroundings:
    """Chances and sizes (metres) of what a crop keeps beside its object."""

    wall: float = 0.5  # the chance of a wall behind one of its sides
    wall_gap_m: tuple[float, float] = (0.0, 0.12)  # from the object's box to the wall
    neighbour: float = 0.35  # the chance of another piece of furniture beside it
    neighbour_gap_m: tuple[float, float] = (0.01, 0.12)
    neighbour_size_m: tuple[float, float] = (0.3, 1.2)  # its width, depth and height
    grow_m: tuple[float, float] = (0.0, 0.15)  # the crop's box grown by this much a side
    floor_removed: float = 0.5  # the chance that a segmenter removed the floor's plane ...
    floor_left_m: tuple[float, float] = (0.01, 0.04)  # ... up to this far above it

    def around(
        self, points: NDArray, spacing: float, radius_m: float, rng: np.random.Generator
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A canonical shape (M, 3), object radii, standing on its lowest point, whose surface
        points lie ``spacing`` apart, an object ``radius_m`` metres in radius -> (the shape with
        its surroundings (M', 3), M' >= M, the shape's rows first; normals (M' - M, 3) of the
        added points, for scanners that see points as discs)."""
        lo, hi = points.min(0), points.max(0)
        metre = 1.0 / radius_m
        reach = lo - 0.25 * metre, hi + 0.25 * metre  # beyond any crop's grown box
        added = [_plane(np.array([reach[0][0], lo[1], reach[0][2]]),
                        np.array([reach[1][0] - reach[0][0], 0.0, 0.0]),
                        np.array([0.0, 0.0, reach[1][2] - reach[0][2]]), spacing, rng)]  # fmt: skip
        if rng.random() < self.wall:
            added.append(_wall(lo, hi, reach, rng.uniform(*self.wall_gap_m) * metre, spacing, rng))
        if rng.random() < self.neighbour:
            gap = rng.uniform(*self.neighbour_gap_m) * metre
            size = rng.uniform(*self.neighbour_size_m, size=3) * metre
            added.append(_neighbour(lo, hi, gap, size, spacing, rng))
        context = np.concatenate([p for p, _ in added])
        normals = np.concatenate([n for _, n in added])
        return np.concatenate([points, context]), normals

    def crop(
        self, canonical: NDArray, object_points: NDArray, radius_m: float, rng: np.random.Generator
    ) -> NDArray[np.bool_]:
        """Which scanned points (K, 3), canonical frame, object radii, a crop keeps: those
        inside the box of the whole object (``object_points`` (M, 3)) grown a random amount a
        side, and, where a segmenter removed the floor, not within a few centimetres of it."""
        metre = 1.0 / radius_m
        grow = rng.uniform(*self.grow_m) * metre
        lo, hi = object_points.min(0), object_points.max(0)
        keep = np.all((canonical >= lo - grow) & (canonical <= hi + grow), axis=1)
        if rng.random() < self.floor_removed:
            keep &= canonical[:, 1] > lo[1] + rng.uniform(*self.floor_left_m) * metre
        return keep


def _plane(
    corner: NDArray, a: NDArray, b: NDArray, spacing: float, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points at random on the parallelogram ``corner + s a + t b`` (s, t in [0, 1]), about
    ``spacing`` apart -> (points (K, 3), their unit normals (K, 3))."""
    area = float(np.linalg.norm(np.cross(a, b)))
    count = max(1, int(area / spacing**2))
    s, t = rng.random((2, count, 1))
    normal = np.cross(a, b) / max(area, 1e-12)
    return corner + s * a + t * b, np.tile(normal, (count, 1))


def _wall(
    lo: NDArray, hi: NDArray, reach: tuple[NDArray, NDArray], gap: float, spacing: float,
    rng: np.random.Generator,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """A vertical wall ``gap`` beyond one side of the box (lo, hi) (+x, -x, +z or -z, chosen at
    random), from the floor up past the crop's reach."""
    axis = int(rng.choice([0, 2]))
    side = 1 if rng.random() < 0.5 else -1
    along = 2 - axis
    corner = np.array(reach[0], dtype=np.float64)
    corner[1] = lo[1]
    corner[axis] = hi[axis] + gap if side > 0 else lo[axis] - gap
    width = np.zeros(3)
    width[along] = reach[1][along] - reach[0][along]
    height = np.array([0.0, reach[1][1] - lo[1], 0.0])
    return _plane(corner, width, height, spacing, rng)


def _neighbour(
    lo: NDArray, hi: NDArray, gap: float, size: NDArray, spacing: float, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A box (its width, depth, height ``size``) standing on the floor ``gap`` beside one side
    of the box (lo, hi), slid along that side at random -> its five faces' points (not its
    bottom) and their outward normals."""
    axis = int(rng.choice([0, 2]))
    side = 1 if rng.random() < 0.5 else -1
    along = 2 - axis
    near = hi[axis] + gap if side > 0 else lo[axis] - gap - size[0]
    start = rng.uniform(lo[along] - size[1], hi[along])
    box_lo = np.empty(3)
    box_lo[axis], box_lo[along], box_lo[1] = near, start, lo[1]
    extent = np.empty(3)
    extent[axis], extent[along], extent[1] = size[0], size[1], size[2]
    faces = []
    for k in (0, 1, 2):
        for end in (0, 1) if k != 1 else (1,):  # no bottom face
            corner = box_lo.copy()
            corner[k] += end * extent[k]
            a, b = np.zeros(3), np.zeros(3)
            u, v = [j for j in range(3) if j != k]
            a[u], b[v] = extent[u], extent[v]
            points, _ = _plane(corner, a, b, spacing, rng)
            outward = np.zeros(3)
            outward[k] = 1.0 if end else -1.0
            faces.append((points, np.tile(outward, (len(points), 1))))
    return np.concatenate([p for p, _ in faces]), np.concatenate([n for _, n in faces])
