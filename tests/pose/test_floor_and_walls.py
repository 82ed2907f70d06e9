"""A cut-out's floor and walls: found where they run on past the object, and only there."""

from __future__ import annotations

import numpy as np
import pytest

from itnet.floor_and_walls import one_view_from, strip_floor_and_walls
from itnet.pose.cloud import Limits, cut_out
from itnet.pose.errors import BadCloudError
from itnet.pose.request import PoseRequest

UP = np.array([0.0, 1.0, 0.0])  # a camera at the origin looking along +z, held level
SPACING = 0.01


def _grid(a: tuple[float, float], b: tuple[float, float], place, spacing=SPACING) -> np.ndarray:
    """Points ``spacing`` apart over [a0, a1] x [b0, b1], placed in 3-D by ``place(u, v)``."""
    u, v = np.meshgrid(np.arange(*a, spacing), np.arange(*b, spacing), indexing="ij")
    return np.stack(place(u.ravel(), v.ravel()), axis=1)


CABINET = (np.array([-0.3, -1.3, 2.7]), np.array([0.3, -0.5, 3.2]))  # its box's corners


def _cabinet(spacing: float = SPACING) -> np.ndarray:
    """What the camera, 1.3 m over the floor (y = -1.3), sees of a cabinet 0.6 wide, 0.8 tall,
    0.5 deep standing on it 2.7 m ahead: its front and its top."""
    front = _grid((-0.3, 0.3), (-1.3, -0.5), lambda u, v: (u, v, np.full_like(u, 2.7)), spacing)
    top = _grid((-0.3, 0.3), (2.7, 3.2), lambda u, v: (u, np.full_like(u, -0.5), v), spacing)
    return np.concatenate([front, top])


def _seen(points: np.ndarray) -> np.ndarray:
    """The points (N, 3) whose ray from the origin does not pass through the cabinet first."""
    low, high = CABINET
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = low / points, high / points  # where each ray crosses each slab, in ray lengths
    enter = np.nanmax(np.minimum(a, b), axis=1)
    leave = np.nanmin(np.maximum(a, b), axis=1)
    return ~((enter <= leave) & (enter < 0.999))


def _cut_out(spacing: float = SPACING) -> tuple[np.ndarray, int, int]:
    """The cabinet cut out by its box grown 0.15 m a side: the floor before and beside it and
    the wall 5 cm behind it, less what the cabinet hides -> (points, floor points, wall points)."""
    floor = _grid((-0.45, 0.45), (2.55, 3.25), lambda u, v: (u, np.full_like(u, -1.3), v), spacing)
    wall = _grid((-0.45, 0.45), (-1.3, -0.35), lambda u, v: (u, v, np.full_like(u, 3.25)), spacing)
    floor, wall = floor[_seen(floor)], wall[_seen(wall)]
    return np.concatenate([_cabinet(spacing), floor, wall]), len(floor), len(wall)


@pytest.mark.parametrize("spacing", [SPACING, 0.004])  # 13,000 points; 84,000 (planes on a sample)
def test_the_floor_and_the_wall_of_a_cut_out_go_and_the_object_stays(spacing: float):
    points, floor, wall = _cut_out(spacing)
    stripped = strip_floor_and_walls(points, UP, viewpoint=[0.0, 0.0, 0.0], metres_per_unit=1.0)
    object_points = len(_cabinet(spacing))
    assert stripped.keep[:object_points].mean() > 0.95  # the cabinet's lowest 2.5 cm go too
    assert not stripped.keep[object_points:].any()
    assert stripped.floor >= floor and stripped.walls >= 0.95 * wall
    assert stripped.taken == len(points) - int(stripped.keep.sum())


def test_the_sensor_is_the_origin_where_the_cloud_is_one_view_from_it():
    points, _, _ = _cut_out()
    assert one_view_from(points, np.zeros(3))
    given = strip_floor_and_walls(points, UP, viewpoint=[0.0, 0.0, 0.0])
    inferred = strip_floor_and_walls(points, UP)
    np.testing.assert_array_equal(inferred.keep, given.keep)
    assert inferred.taken > 0


def test_a_whole_shape_or_a_cloud_from_elsewhere_is_not_one_view_and_keeps_everything():
    rng = np.random.default_rng(0)
    box = rng.uniform(-1, 1, size=(3000, 3))
    box[np.arange(3000), rng.integers(0, 3, 3000)] = rng.choice([-1.0, 1.0], 3000)  # faces
    ahead = box * [0.3, 0.4, 0.25] + [0.0, -0.9, 3.0]
    assert not one_view_from(ahead, np.zeros(3))  # its back shows through its front
    assert strip_floor_and_walls(ahead, UP).taken == 0
    points, _, _ = _cut_out()
    assert strip_floor_and_walls(points - [0.0, 0.0, 2.9], UP).taken == 0  # origin inside it


def test_an_object_alone_keeps_its_seat_its_back_and_its_base():
    seat = _grid((-0.25, 0.25), (2.5, 2.95), lambda u, v: (u, np.full_like(u, -0.85), v))
    back = _grid((-0.25, 0.25), (-0.85, -0.2), lambda u, v: (u, v, np.full_like(u, 2.95)))
    chair = np.concatenate([seat, back])  # its legs hidden: the seat is its lowest level face
    for points in (chair, _cabinet()):
        assert strip_floor_and_walls(points, UP, [0.0, 0.0, 0.0], 1.0).taken == 0


def _monitor_from_behind() -> tuple[np.ndarray, int]:
    """What the camera sees of a monitor standing 2 m ahead, its back to it -> (points, how many
    of them are the screen's flat back): the back (0.54 wide), less what the casing hides, the
    casing's back 7 cm nearer, the stand's neck and the top of its base, which reaches 15 cm
    out from the screen."""
    panel = _grid((-0.27, 0.27), (-0.55, -0.22), lambda u, v: (u, v, np.full_like(u, 2.0)))
    panel = panel[~((np.abs(panel[:, 0]) < 0.15) & (panel[:, 1] > -0.5) & (panel[:, 1] < -0.3))]
    casing = _grid((-0.15, 0.15), (-0.5, -0.3), lambda u, v: (u, v, np.full_like(u, 1.93)))
    neck = _grid((-0.03, 0.03), (-0.75, -0.5), lambda u, v: (u, v, np.full_like(u, 1.95)))
    base = _grid((-0.1, 0.1), (1.85, 2.05), lambda u, v: (u, np.full_like(u, -0.75), v))
    return np.concatenate([panel, casing, neck, base]), len(panel)


def test_a_flat_back_with_a_shallow_object_before_it_is_not_a_wall():
    points, panel = _monitor_from_behind()
    assert strip_floor_and_walls(points, UP, [0.0, 0.0, 0.0], 1.0).taken == 0
    deep = points.copy()  # the same with what stands before it 0.37 m out: the flat back goes
    deep[panel:, 2] -= np.where(deep[panel:, 1] > -0.75, 0.3, 0.0)
    before_it = strip_floor_and_walls(deep, UP, [0.0, 0.0, 0.0], 1.0)
    assert before_it.walls >= panel and before_it.keep[panel:].mean() > 0.95


def test_nothing_goes_where_too_little_would_be_left():
    points, _, _ = _cut_out()
    sliver = _cabinet()[::40]
    few = np.concatenate([sliver, points[len(_cabinet()) :]])
    stripped = strip_floor_and_walls(few, UP, [0.0, 0.0, 0.0], 1.0)
    assert stripped.taken == 0 and stripped.keep.all()


def test_a_request_strips_by_default_where_up_is_given_and_says_so():
    points, _, _ = _cut_out()
    kept, stripped = cut_out(points, PoseRequest(up=[0.0, 1.0, 0.0], units="m"), Limits())
    assert stripped is not None and len(kept) == len(points) - stripped.taken
    assert cut_out(points, PoseRequest(), Limits()) == (points, None)  # no up: as sent
    off = PoseRequest(up=[0.0, 1.0, 0.0], strip=False)
    assert cut_out(points, off, Limits())[1] is None
    with pytest.raises(BadCloudError, match="strip needs 'up'"):
        cut_out(points, PoseRequest(strip=True), Limits())
    with pytest.raises(BadCloudError, match="NaN"):
        cut_out(np.full((40, 3), np.nan), PoseRequest(up=[0.0, 1.0, 0.0]), Limits())
