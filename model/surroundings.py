"""What a box cut out of a room keeps beside its object: floor, wall, a neighbour, things on it.

A real object is never scanned alone. Cut out of a depth frame by its box, or by a segmenter
that removed the floor and the walls as planes, it keeps a strip of the floor it stands on (a
user's box grown a little below its base; a segmenter's plane removal leaves the floor's noisy
top), a strip of the wall it stands against (night stands, dressers and beds stand there), a
piece of whatever stands beside it (a bed beside a night stand, a table beside a chair), and
what stands on it: a lamp on a night stand, a mirror, books and a vase on a dresser, boxes on a
table. A user's box holds the foot of those things (they rise above the piece's box); a
segmenter's cluster holds them whole.

``Surroundings.around`` adds such surfaces, as points, around a canonical shape (object radii,
+y up, the front towards -z) before it is scanned, so that the scanner's z-buffer hides what the
object hides and the sensor model treats them as it treats the object; ``Surroundings.crop``
then keeps what the object's box, grown, holds. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

ON_TOP_COUNT = (1, 3)  # things standing on a piece that carries any (inclusive)


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
    on_top: float = 0.0  # the chance that things stand on the piece (``on_top_things``) ...
    on_top_count: tuple[int, int] = ON_TOP_COUNT  # ... this many of them (inclusive)
    on_top_kept: float = 0.5  # the chance that the crop's box holds them whole (a segmenter's)

    def around(
        self, points: NDArray, spacing: float, radius_m: float, rng: np.random.Generator
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
        """A canonical shape (M, 3), object radii, standing on its lowest point, whose surface
        points lie ``spacing`` apart, an object ``radius_m`` metres in radius -> (the shape with
        its surroundings (M', 3), M' >= M, the shape's rows first; normals (M' - M, 3) of the
        added points, for scanners that see points as discs; how many of the first rows the
        crop's box is drawn around: M, or M and the things standing on the shape)."""
        lo, hi = points.min(0), points.max(0)
        metre = 1.0 / radius_m
        things: list[tuple[NDArray, NDArray]] = []
        boxed = len(points)
        if self.on_top > 0 and rng.random() < self.on_top:  # no draw without: crops as before
            count = int(rng.integers(self.on_top_count[0], self.on_top_count[1] + 1))
            things = on_top_things(points, count, spacing, metre, rng)
            if rng.random() < self.on_top_kept:
                boxed += sum(len(p) for p, _ in things)
        if things:
            grown = np.concatenate([points] + [p for p, _ in things])
            lo, hi = grown.min(0), grown.max(0)  # walls and neighbours beyond the things too
        reach = lo - 0.25 * metre, hi + 0.25 * metre  # beyond any crop's grown box
        added = [*things, _plane(np.array([reach[0][0], lo[1], reach[0][2]]),
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
        return np.concatenate([points, context]), normals, boxed

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
    return _box_faces(box_lo, extent, spacing, rng)


def _box_faces(
    box_lo: NDArray, extent: NDArray, spacing: float, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """An axis-aligned box from ``box_lo`` (3,) spanning ``extent`` (3,) -> its five faces'
    points (not its bottom) and their outward normals."""
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


ON_TOP_KINDS = {"lamp": 0.3, "box": 0.25, "vase": 0.15, "plant": 0.1, "mirror": 0.2}
"""What stands on a piece of furniture, and how often: a table lamp, a box or a pile of books, a
vase, a potted plant, a mirror or picture frame standing at the back of its top."""
TOP_LEAST_M = 0.25  # a top this high over the floor or higher can carry things


def on_top_things(
    points: NDArray, count: int, spacing: float, metre: float, rng: np.random.Generator
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``count`` things (``ON_TOP_KINDS``, at retail sizes) standing on the tops of a canonical
    shape (M, 3) standing on its lowest point, ``metre`` object radii a metre -> each thing's
    points and their unit normals; none where the shape has no top."""
    tops = top_points(points, spacing, metre, rng)
    if len(tops) == 0:
        return []
    kinds, chances = list(ON_TOP_KINDS), np.array(list(ON_TOP_KINDS.values()))
    things = []
    for _ in range(count):
        at = points[tops[rng.integers(len(tops))]]
        kind = kinds[int(rng.choice(len(kinds), p=chances / chances.sum()))]
        if kind == "mirror":
            things.append(_mirror(at, points[tops], spacing, metre, rng))
        else:
            things.append(_standing(kind, at, spacing, metre, rng))
    return things


def top_points(
    points: NDArray, spacing: float, metre: float, rng: np.random.Generator, tries: int = 400
) -> NDArray[np.intp]:
    """Rows of a canonical shape (M, 3) that lie on a top something can stand on: at least
    ``TOP_LEAST_M`` over its lowest point, nothing of the shape above them within 4 cm across,
    and at least three of its points within 1 cm below them there (a surface, not an edge).
    Judged for up to ``tries`` rows drawn at random."""
    floor = points[:, 1].min()
    high = np.flatnonzero(points[:, 1] >= floor + TOP_LEAST_M * metre)
    if len(high) == 0:
        return high
    rows = rng.choice(high, size=min(tries, len(high)), replace=False)
    across = np.linalg.norm(points[rows][:, None, [0, 2]] - points[None, :, [0, 2]], axis=2)
    column = across < max(0.04 * metre, 1.5 * spacing)
    rise = points[None, :, 1] - points[rows][:, None, 1]
    clear = ~(column & (rise > 0.01 * metre)).any(1)
    flat = (column & (rise > -0.01 * metre)).sum(1) >= 3
    return rows[clear & flat]


def _standing(
    kind: str, at: NDArray, spacing: float, metre: float, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A lamp, box, vase or plant (metres turned into object radii by ``metre``) standing
    at ``at`` (3,) -> its points and unit normals."""
    u = rng.uniform
    if kind == "box":
        size = np.array([u(0.1, 0.45), u(0.03, 0.3), u(0.1, 0.35)]) * metre
        p, n = _box_faces(np.array([-size[0] / 2, 0.0, -size[2] / 2]), size, spacing, rng)
        turn = u(0, 2 * np.pi)
        c, s = np.cos(turn), np.sin(turn)
        yaw = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        return p @ yaw.T + at, n @ yaw.T
    if kind == "vase":
        return _cylinder(at, u(0.04, 0.12) * metre, u(0.04, 0.12) * metre,
                         u(0.1, 0.4) * metre, spacing, rng, cap=True)  # fmt: skip
    if kind == "plant":
        pot_r, pot_h = u(0.06, 0.12) * metre, u(0.08, 0.2) * metre
        pot = _cylinder(at, pot_r, pot_r * u(1.0, 1.3), pot_h, spacing, rng, cap=False)
        spread = u(0.1, 0.25) * metre
        count = max(8, int(4 * np.pi * spread**2 / spacing**2))
        normals = rng.normal(size=(count, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        middle = at + np.array([0.0, pot_h + spread, 0.0])
        leaves = middle + normals * spread * rng.random((count, 1)) ** 0.3
        return np.concatenate([pot[0], leaves]), np.concatenate([pot[1], normals])
    if kind == "lamp":
        pole_h = u(0.2, 0.45) * metre
        parts = [
            _cylinder(at, u(0.05, 0.1) * metre, None, u(0.02, 0.05) * metre, spacing, rng, True),
            _cylinder(at, u(0.01, 0.06) * metre, None, pole_h, spacing, rng, cap=False),
        ]
        shade_h = u(0.15, 0.3) * metre
        bottom = at + np.array([0.0, pole_h - 0.3 * shade_h, 0.0])
        shade_r = u(0.12, 0.22) * metre
        parts.append(_cylinder(bottom, shade_r, shade_r * u(0.55, 0.85), shade_h, spacing, rng,
                               cap=False))  # fmt: skip
        return np.concatenate([p for p, _ in parts]), np.concatenate([n for _, n in parts])
    raise ValueError(f"unknown thing {kind!r} (known: {', '.join(ON_TOP_KINDS)})")


def _mirror(
    at: NDArray, tops: NDArray, spacing: float, metre: float, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A mirror or picture frame standing at the back (+z) of the top through ``at`` (3,) (the
    top's points ``tops`` (T, 3)), facing the front, at most as wide as the top."""
    level = tops[np.abs(tops[:, 1] - at[1]) < 0.02 * metre]
    left, right, back = level[:, 0].min(), level[:, 0].max(), level[:, 2].max()
    width = min(rng.uniform(0.4, 1.0) * metre, 0.9 * (right - left) + 1e-9)
    height, depth = rng.uniform(0.3, 1.0) * metre, rng.uniform(0.02, 0.05) * metre
    centre = np.clip(at[0], left + width / 2, right - width / 2) if right - left > width else (
        (left + right) / 2
    )  # fmt: skip
    box_lo = np.array([centre - width / 2, at[1], back - depth - 0.02 * metre * rng.random()])
    return _box_faces(box_lo, np.array([width, height, depth]), spacing, rng)


def _cylinder(
    base: NDArray, radius: float, top_radius: float | None, height: float, spacing: float,
    rng: np.random.Generator, cap: bool,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """An upright open cylinder (a cone's frustum where ``top_radius`` is given) standing at
    ``base`` (3,), with its top closed where ``cap`` -> its points and unit normals (across the
    side; +y on the cap)."""
    top = radius if top_radius is None else top_radius
    side = np.pi * (radius + top) * height
    count = max(8, int(side / spacing**2))
    t, angle = rng.random(count), rng.uniform(0, 2 * np.pi, count)
    r = radius + (top - radius) * t
    across = np.stack([np.cos(angle), np.zeros(count), np.sin(angle)], 1)
    points = base + across * r[:, None] + np.outer(height * t, [0.0, 1.0, 0.0])
    normals = across
    if cap:
        k = max(4, int(np.pi * top**2 / spacing**2))
        a, rr = rng.uniform(0, 2 * np.pi, k), top * np.sqrt(rng.random(k))
        disc = base + np.stack([rr * np.cos(a), np.full(k, height), rr * np.sin(a)], 1)
        points = np.concatenate([points, disc])
        normals = np.concatenate([normals, np.tile([0.0, 1.0, 0.0], (k, 1))])
    return points, normals
