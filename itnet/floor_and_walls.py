"""The floor and walls a cut-out keeps, found and taken away before it is classified and posed.

An object cut out of a depth frame or a room by its box (a user's, grown a little) keeps a strip
of the floor it stands on and of the wall behind it; the networks were trained on the object
alone, and take the strips for part of it. Given which way is up, both are planes of known
direction at the cut-out's edge, and where they are found they go:

* **The floor**: among the points within 0.25 m of the lowest (its 1st percentile of heights),
  the plane within 15 degrees of level that holds most of them (RANSAC, ``itnet.planes``). It is
  the floor where the sensor stands at least 0.1 m above it (from above, the only level surface
  at an object's foot is the floor: its own underside shows from below only), at least 2% of
  the points lie within 2.5 cm of it and at most 2% more than 5 cm below it. Everything less
  than 2.5 cm above it goes.
* **The walls**: upright planes (normals within 10 degrees of level; up to four tried, two
  kept, since an object's own front may hold more points than the wall) at the cut-out's far
  side: each holds at least 5% of what is left, at least 30% of what is left lies off it, and
  at most 2% of that more than 5 cm behind it, seen from the sensor (an object's own face has
  the rest of the object behind it), and what stands before it reaches at least 0.2 m out from
  it (furniture is that deep; a monitor's flat back, its casing and stand a few centimetres
  before it, is no wall). Everything less than 2.5 cm before it goes.
* Each only where it **runs on past the object** (what lies on no floor or wall found) by more
  than 5 cm: the floor at both ends of one direction along it, a wall at either end of its
  width. A chair's seat, a sofa's back or a cabinet's front ends with the object, and stays.
* Nothing goes where less than a quarter of the cloud, or fewer than 32 points, would be left.
* The planes are found on at most 20,000 of the points (a real frame's bed cropped whole has
  111,000), then every point is labelled by them: the time stays under about 20 ms.

Distances are in metres where the cloud's unit is known, otherwise in proportion to its size
(an RMS radius of 0.4 m). The sensor is the ``viewpoint`` given, or the origin where the cloud is
one view from it (``one_view_from``: a depth camera's cloud in its own frame); without either
nothing is taken, since which side a plane is seen from decides both tests.
Pure numpy (and scipy's KD-tree).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from itnet.planes import Plane, floor_axes, ransac_plane
from itnet.preprocess import DegenerateCloudError, estimate_normalization

TOLERANCE_M = 0.025  # a point within this of a floor or wall is on it
FLOOR_BAND_M = 0.25  # the floor is looked for this far above the lowest points
SENSOR_ABOVE_M = 0.1  # the sensor stands at least this far above a floor
FLOOR_TILT_DEG = 15.0
WALL_TILT_DEG = 10.0
FLOOR_SHARE = 0.02  # the least share of the points on a floor ...
BELOW_SHARE = 0.02  # ... and the most below it (beyond twice the tolerance)
WALL_SHARE = 0.05  # the least share of what is left on a wall ...
OFF_WALL_SHARE = 0.3  # ... and off it ...
BEHIND_SHARE = 0.02  # ... and the most of that behind it (beyond twice the tolerance)
DEPTH_M = 0.2  # what stands before a wall reaches at least this far out from it
WALLS = 2
WALL_TRIES = 4  # upright planes tried: an object's own face may hold more points than a wall
LEFT_SHARE = 0.25  # nothing goes where less than this share of the cloud would be left
MIN_LEFT = 32
SIZE_M = 0.4  # the RMS radius taken for a cloud of unknown unit
SAMPLE_POINTS = 20_000  # the planes are found on at most this many of the points
HIDDEN_SHARE = 0.05  # one view: at most this share hidden behind nearer points ...
HIDDEN_CELLS = 6.0  # ... by more than this many cells' width (a surface seen at 10 degrees)
VIEW_HALF_ANGLE_DEG = 80.0  # one view: every point within this of its mean direction


@dataclass(frozen=True)
class Stripped:
    """What was taken away: ``keep`` (N,) bool, the points left; ``floor`` and ``walls``, how
    many points each took."""

    keep: NDArray[np.bool_]
    floor: int
    walls: int

    @property
    def taken(self) -> int:
        return self.floor + self.walls

    def as_dict(self) -> dict:
        return {"floor": self.floor, "walls": self.walls}


def one_view_from(points: NDArray, viewpoint: ArrayLike) -> bool:
    """Whether a cloud (N, 3) looks like one view from ``viewpoint`` (3,): every point within
    80 degrees of the cloud's mean direction from it, and at most 5% of the points hidden
    behind a nearer one in the same direction (a cell of twice the points' usual angular
    spacing, hidden beyond six cells' width: a surface seen at 10 degrees is not). A fused
    scan, a whole shape or a cloud around the point is not."""
    rel = np.asarray(points, np.float64) - np.asarray(viewpoint, np.float64)
    depth = np.linalg.norm(rel, axis=1)
    if len(rel) < 3 or depth.min() <= 0:
        return False
    axis = (rel / depth[:, None]).mean(axis=0)
    norm = float(np.linalg.norm(axis))
    if norm < 1e-9:
        return False
    axis /= norm
    ahead = rel @ axis
    if np.min(ahead / depth) < math.cos(math.radians(VIEW_HALF_ANGLE_DEG)):
        return False
    first = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    image = np.c_[rel @ first, rel @ np.cross(axis, first)] / ahead[:, None]  # (N, 2) tangents
    sample = image[np.random.default_rng(0).permutation(len(image))[:2000]]
    spacing = float(np.median(cKDTree(sample).query(sample, k=2)[0][:, 1]))
    cell = 2.0 * max(spacing, 1e-9)
    cells = np.floor(image / cell).astype(np.int64)
    cells -= cells.min(axis=0)
    _, which = np.unique(cells[:, 0] * (cells[:, 1].max() + 1) + cells[:, 1], return_inverse=True)
    nearest = np.full(which.max() + 1, np.inf)
    np.minimum.at(nearest, which, depth)
    hidden = depth > nearest[which] + HIDDEN_CELLS * cell * depth
    return float(hidden.mean()) <= HIDDEN_SHARE


def strip_floor_and_walls(
    points: ArrayLike,
    up: ArrayLike,
    viewpoint: ArrayLike | None = None,
    metres_per_unit: float | None = None,
    seed: int = 0,
) -> Stripped:
    """A cut-out (N, 3), its unit up (3,), the sensor (3,) if known, the cloud's unit in metres
    if known -> what of it is floor and walls (see the module). The planes are found on at most
    ``SAMPLE_POINTS`` of the points, then every point is labelled by them."""
    cloud = np.asarray(points, np.float64)
    up_unit = np.asarray(up, np.float64) / np.linalg.norm(up)
    rng = np.random.default_rng(seed)
    sample = cloud
    if len(cloud) > SAMPLE_POINTS:
        sample = cloud[rng.choice(len(cloud), SAMPLE_POINTS, replace=False)]
    keep = np.ones(len(cloud), bool)
    sensor = _sensor(sample, viewpoint)
    if sensor is None or len(cloud) < MIN_LEFT:
        return Stripped(keep, 0, 0)
    metre = _units_per_metre(sample, metres_per_unit)
    if metre is None:
        return Stripped(keep, 0, 0)
    floor, walls = _planes(sample, up_unit, sensor, metre, rng)
    found = ([floor] if floor is not None else []) + walls
    taken = _take(cloud, [plane for plane, _ in found], TOLERANCE_M * metre)
    for (_, goes), gone in zip(found, taken):
        if goes:
            keep &= ~gone
    floor_taken = int(taken[0].sum()) if floor is not None and floor[1] else 0
    if keep.sum() < max(MIN_LEFT, LEFT_SHARE * len(cloud)):
        return Stripped(np.ones(len(cloud), bool), 0, 0)
    return Stripped(keep, floor_taken, int((~keep).sum()) - floor_taken)


def _take(cloud: NDArray, planes: list[Plane], tolerance: float) -> list[NDArray[np.bool_]]:
    """Planes facing the points they take -> each one's points (N,) of the cloud (N, 3): those
    less than the tolerance before it that no plane before it took."""
    taken, masks = np.zeros(len(cloud), bool), []
    for plane in planes:
        masks.append(~taken & (plane.distance(cloud) < tolerance))
        taken |= masks[-1]
    return masks


def _planes(
    cloud: NDArray, up: NDArray, sensor: NDArray, metre: float, rng: np.random.Generator
) -> tuple[tuple[Plane, bool] | None, list[tuple[Plane, bool]]]:
    """The floor (or None) and walls of a cloud (N, 3), each a plane facing the points it
    takes, and whether it goes (runs on past the object)."""
    tolerance = TOLERANCE_M * metre
    floor = _floor(cloud, up, sensor, metre, rng)
    taken = (
        floor[0].distance(cloud) < tolerance if floor is not None else np.zeros(len(cloud), bool)
    )
    looked = taken.copy()  # planes already tried: found walls, and faces that are none
    walls: list[tuple[Plane, NDArray[np.bool_], NDArray[np.float64]]] = []
    for _ in range(WALL_TRIES):
        wall = _wall(cloud, ~taken, ~looked, up, sensor, metre, rng)
        if wall is None:
            break
        on, facing, along = wall
        looked |= on
        if facing is not None:
            gone = ~taken & (facing.distance(cloud) < tolerance)
            walls.append((facing, gone, along))
            taken |= gone
            if len(walls) == WALLS:
                break
    rest = cloud[~taken]  # the object: what lies on no floor or wall found
    found_walls = [(facing, _reaches_past(cloud[gone], rest, along, tolerance, both_ends=False))
                   for facing, gone, along in walls]  # fmt: skip
    if floor is None:
        return None, found_walls
    on_floor = cloud[np.abs(floor[0].distance(cloud)) < tolerance]
    goes = any(_reaches_past(on_floor, rest, axis, tolerance, both_ends=True) for axis in floor[1])
    return (floor[0], goes), found_walls


def _sensor(cloud: NDArray, viewpoint: ArrayLike | None) -> NDArray[np.float64] | None:
    """The viewpoint given, else the origin where the cloud is one view from it, else None."""
    if viewpoint is not None:
        return np.asarray(viewpoint, np.float64)
    origin = np.zeros(3)
    return origin if one_view_from(cloud, origin) else None


def _units_per_metre(cloud: NDArray, metres_per_unit: float | None) -> float | None:
    """The cloud's units in a metre: from its unit, else from its RMS radius (the networks'
    normalisation, ``itnet.preprocess``) taken as ``SIZE_M``; None for a cloud with no extent."""
    if metres_per_unit is not None:
        return 1.0 / metres_per_unit
    try:
        return estimate_normalization(cloud).scale / SIZE_M
    except DegenerateCloudError:
        return None


def _floor(
    cloud: NDArray, up: NDArray, sensor: NDArray, metre: float, rng: np.random.Generator
) -> tuple[Plane, tuple[NDArray, NDArray]] | None:
    """A floor under the cloud (N, 3) -> (its plane, normal up, two directions along it (3,)),
    or None where there is none."""
    tolerance = TOLERANCE_M * metre
    height = cloud @ up
    band = height <= np.percentile(height, 1) + FLOOR_BAND_M * metre
    level = math.cos(math.radians(FLOOR_TILT_DEG))
    found = ransac_plane(
        cloud[band], rng, tolerance, lambda normals: np.abs(normals @ up) > level,
        hypotheses=100, sample=1000, refine=4000,
    )  # fmt: skip
    if found is None:
        return None
    plane = found[0].toward(up)
    above = plane.distance(cloud)
    on = np.abs(above) < tolerance
    if (
        plane.distance(sensor[None])[0] < SENSOR_ABOVE_M * metre
        or on.sum() < max(10, FLOOR_SHARE * len(cloud))
        or (above < -2 * tolerance).sum() > BELOW_SHARE * len(cloud)
    ):
        return None
    return plane, floor_axes(plane.normal)


def _wall(
    cloud: NDArray,
    left: NDArray[np.bool_],
    untried: NDArray[np.bool_],
    up: NDArray,
    sensor: NDArray,
    metre: float,
    rng: np.random.Generator,
) -> tuple[NDArray[np.bool_], Plane | None, NDArray[np.float64]] | None:
    """The likeliest upright plane through the ``untried`` points (N,) of the cloud (N, 3) ->
    (its points (N,), the plane facing the sensor where it is a wall behind the points ``left``
    (N,) or else None, its level direction (3,)), or None where there is no plane. ``metre``:
    the cloud's units in a metre."""
    tolerance = TOLERANCE_M * metre
    upright = math.sin(math.radians(WALL_TILT_DEG))
    found = ransac_plane(
        cloud[untried], rng, tolerance, lambda normals: np.abs(normals @ up) < upright,
        hypotheses=100, sample=1000, refine=4000,
    )  # fmt: skip
    if found is None:
        return None
    along = np.cross(found[0].normal, up)
    side = float(found[0].distance(sensor[None])[0])
    facing = found[0].toward(found[0].normal * side)  # its normal toward the sensor
    before = facing.distance(cloud)
    on = left & (np.abs(before) < tolerance)
    off = left & ~on
    if (
        abs(side) < tolerance
        or on.sum() < WALL_SHARE * left.sum()
        or off.sum() < OFF_WALL_SHARE * left.sum()
        or (off & (before < -2 * tolerance)).sum() > BEHIND_SHARE * off.sum()
        or not off.any()
        or np.percentile(before[off], 98) < DEPTH_M * metre
    ):
        return untried & (np.abs(before) < tolerance), None, along
    return on, facing, along


def _reaches_past(
    plane: NDArray, rest: NDArray, axis: NDArray, tolerance: float, both_ends: bool
) -> bool:
    """Whether a plane's points (K, 3) reach past the rest (M, 3) along ``axis`` (3,), by more
    than twice the tolerance, at both its ends or at either: a floor or a wall runs on past
    the object beside it, where the object's own seat, base or back ends with it."""
    if len(plane) == 0 or len(rest) == 0:
        return len(plane) > 0
    on, off = np.percentile(plane @ axis, [1, 99]), np.percentile(rest @ axis, [1, 99])
    past = (off[0] - on[0] > 2 * tolerance, on[1] - off[1] > 2 * tolerance)
    return all(past) if both_ends else any(past)
