"""What a box cut out of a room keeps beside its object: floor, wall and a neighbour's side.

A real object is never scanned alone. Cut out of a depth frame by its box, or by a segmenter
that removed the floor and the walls as planes, it keeps a strip of the floor it stands on (a
user's box grown a little below its base; a segmenter's plane removal leaves the floor's noisy
top), a strip of the wall it stands against (night stands, dressers and beds stand there), a
piece of whatever stands beside it (a bed beside a night stand, a table beside a chair), and
what stands on its top where that is a shelf (a table lamp on a night stand, a mirror standing
on a dresser, a box or books on a table or a desk): a segmenter's cluster holds it whole, an
annotator's box often does.

``Surroundings.around`` adds such surfaces, as points, around a canonical shape (object radii,
+y up) before it is scanned, so that the scanner's z-buffer hides what the object hides and the
sensor model treats them as it treats the object; ``Surroundings.crop`` then keeps what the
object's box, grown, holds. Pure numpy.
"""

from __future__ import annotations

import math
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
    on_top: float = 0.4  # the chance of a thing standing on a top that is a shelf ...
    on_top_kinds: tuple[float, float, float] = (0.5, 0.3, 0.2)  # ... a lamp, a box, a mirror
    top_reached: float = 0.5  # the chance that the crop's box reaches up over what stands on it
    top_reach_m: tuple[float, float] = (0.2, 1.2)  # ... by this much

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
            tall = (reach[0], reach[1] + [0.0, self.top_reach_m[1] * metre, 0.0])  # past any crop
            added.append(_wall(lo, hi, tall, rng.uniform(*self.wall_gap_m) * metre, spacing, rng))
        if rng.random() < self.neighbour:
            gap = rng.uniform(*self.neighbour_gap_m) * metre
            size = rng.uniform(*self.neighbour_size_m, size=3) * metre
            added.append(_neighbour(lo, hi, gap, size, spacing, rng))
        if rng.random() < self.on_top:
            added += _on_top(points, metre, spacing, self.on_top_kinds, rng)
        context = np.concatenate([p for p, _ in added])
        normals = np.concatenate([n for _, n in added])
        return np.concatenate([points, context]), normals

    def crop(
        self, canonical: NDArray, object_points: NDArray, radius_m: float, rng: np.random.Generator
    ) -> NDArray[np.bool_]:
        """Which scanned points (K, 3), canonical frame, object radii, a crop keeps: those
        inside the box of the whole object (``object_points`` (M, 3)) grown a random amount a
        side (and up over what stands on it, at times), and, where a segmenter removed the
        floor, not within a few centimetres of it."""
        metre = 1.0 / radius_m
        grow = rng.uniform(*self.grow_m) * metre
        lo, hi = object_points.min(0), object_points.max(0).copy()
        if rng.random() < self.top_reached:
            hi[1] += rng.uniform(*self.top_reach_m) * metre
        keep = np.all((canonical >= lo - grow) & (canonical <= hi + grow), axis=1)
        if rng.random() < self.floor_removed:
            keep &= canonical[:, 1] > lo[1] + rng.uniform(*self.floor_left_m) * metre
        return keep


SHELF_M = 0.03  # a top's points lie within this of its highest
SHELF_LEAST_M = 0.25  # a shelf is at least this deep and wide ...
SHELF_COVER = 0.4  # ... and its points cover at least this share of its box


def _on_top(
    points: NDArray, metre: float, spacing: float, kinds: tuple[float, float, float],
    rng: np.random.Generator,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:  # fmt: skip
    """A thing standing on a shape's (M, 3) top where that is a shelf (flat, at least
    ``SHELF_LEAST_M`` across both ways: a table's, a night stand's, a dresser's; not a chair's
    back or a bathtub's rim), ``metre`` units a metre, its surface ``spacing`` apart: a table
    lamp, a box, or a mirror standing along one of its long edges (``kinds``: their chances) ->
    its surfaces (points (K, 3), normals (K, 3)), none where the top is no shelf."""
    top = float(points[:, 1].max())
    shelf = points[points[:, 1] > top - SHELF_M * metre][:, [0, 2]]
    lo, hi = np.percentile(shelf, 2, axis=0), np.percentile(shelf, 98, axis=0)
    span = hi - lo
    if np.any(span < SHELF_LEAST_M * metre) or len(shelf) < SHELF_COVER * span.prod() / spacing**2:
        return []
    kind = int(rng.choice(3, p=np.asarray(kinds) / sum(kinds)))
    if kind == 2:  # a mirror along a long edge, its back flush with it
        long = int(span[1] > span[0])
        width = min(rng.uniform(0.6, 1.0) * span[long], 1.2 * metre)
        size = np.array([width, rng.uniform(0.5, 1.0) * metre, rng.uniform(0.02, 0.05) * metre])
        if long == 1:
            size = size[[2, 1, 0]]
        edge = lo[1 - long] if rng.random() < 0.5 else hi[1 - long] - size[2 * (1 - long)]
        corner = np.array([0.0, top, 0.0])
        corner[2 * (1 - long)] = edge
        corner[2 * long] = rng.uniform(lo[long], max(lo[long], hi[long] - size[2 * long]))
        return _box(corner, size, spacing, rng)
    if kind == 1:  # a box, books, a speaker
        size = rng.uniform([0.1, 0.05, 0.1], [0.4, 0.3, 0.3]) * metre
        where = rng.uniform(lo, np.maximum(lo, hi - size[[0, 2]]))
        return _box(np.array([where[0], top, where[1]]), size, spacing, rng)
    centre = rng.uniform(lo + 0.1 * metre, np.maximum(lo + 0.1 * metre, hi - 0.1 * metre))
    stem = rng.uniform(0.15, 0.35) * metre
    shade = rng.uniform(0.1, 0.2) * metre
    return [
        _cylinder(centre, top, rng.uniform(0.05, 0.1) * metre, None, 0.02 * metre, spacing, rng),
        _cylinder(centre, top, 0.01 * metre, None, stem, spacing, rng),
        _cylinder(centre, top + stem - 0.05 * metre, shade, shade * rng.uniform(0.5, 0.9),
                  rng.uniform(0.15, 0.3) * metre, spacing, rng),
    ]  # fmt: skip


def _cylinder(
    centre: NDArray, base: float, radius: float, top_radius: float | None, height: float,
    spacing: float, rng: np.random.Generator,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Points about ``spacing`` apart on an upright cylinder's side and top (``top_radius``
    None), or an open cone's side (a lamp's shade), standing at ``centre`` (x, z) on y =
    ``base`` -> (points (K, 3), their unit normals (K, 3))."""
    closed = top_radius is None
    upper = radius if top_radius is None else top_radius
    side = math.pi * (radius + upper) * math.hypot(height, radius - upper)
    cap = math.pi * upper**2 if closed else 0.0
    count = max(8, int((side + cap) / spacing**2))
    on_cap = rng.random(count) < cap / (side + cap)
    t = rng.random(count)
    angle = rng.uniform(0.0, 2 * math.pi, count)
    r = np.where(on_cap, upper * np.sqrt(rng.random(count)), radius + (upper - radius) * t)
    y = np.where(on_cap, 1.0, t) * height
    points = np.stack([centre[0] + r * np.cos(angle), base + y, centre[1] + r * np.sin(angle)], 1)
    normals = np.stack([np.cos(angle), np.zeros(count), np.sin(angle)], 1)
    normals[on_cap] = [0.0, 1.0, 0.0]
    return points, normals


def _box(
    corner: NDArray, size: NDArray, spacing: float, rng: np.random.Generator
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """A box's five faces (not its bottom) from ``corner`` (3,) (its least x, y, z) across
    ``size`` (3,) -> each face's (points, outward normals)."""
    faces = []
    for k in (0, 1, 2):
        for end in (0, 1) if k != 1 else (1,):
            start = np.asarray(corner, dtype=np.float64).copy()
            start[k] += end * size[k]
            a, b = np.zeros(3), np.zeros(3)
            u, v = [j for j in range(3) if j != k]
            a[u], b[v] = size[u], size[v]
            points, _ = _plane(start, a, b, spacing, rng)
            outward = np.zeros(3)
            outward[k] = 1.0 if end else -1.0
            faces.append((points, np.tile(outward, (len(points), 1))))
    return faces


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
    faces = _box(box_lo, extent, spacing, rng)
    return np.concatenate([p for p, _ in faces]), np.concatenate([n for _, n in faces])
