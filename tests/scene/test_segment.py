import math

import numpy as np
from scene_helpers import boxes_shape, chair_shape, make_test_scene

from itnet.planes import fit_plane, ransac_plane
from itnet.scene import from_depth
from itnet.scene.segment import segment


def test_fit_plane_recovers_a_plane():
    rng = np.random.default_rng(0)
    normal = np.array([0.2, -0.9, 0.1]) / np.linalg.norm([0.2, -0.9, 0.1])
    basis = np.linalg.svd(normal[None])[2][1:]  # two directions in the plane
    points = rng.uniform(-2, 2, size=(500, 2)) @ basis - 1.3 * normal
    plane = fit_plane(points)
    assert abs(abs(plane.normal @ normal) - 1) < 1e-9
    np.testing.assert_allclose(plane.distance(points), 0, atol=1e-9)


def test_floor_and_up_from_a_tilted_camera():
    """A floor 1.4 m below a camera pitched 20 degrees down and rolled 5: up is the floor's
    normal toward the camera, whatever the clutter."""
    rng = np.random.default_rng(1)
    pitch, roll = math.radians(20), math.radians(5)
    up = np.array([math.sin(roll), -math.cos(pitch), -math.sin(pitch)])
    up /= np.linalg.norm(up)
    basis = np.linalg.svd(up[None])[2][1:]  # two directions in the floor
    floor = rng.uniform(-8, 8, size=(8000, 2)) @ basis - 1.4 * up
    floor = floor[(floor[:, 2] > 1.0) & (floor[:, 2] < 6.0)]  # what the camera sees
    floor += rng.normal(scale=0.005, size=floor.shape)
    clutter = rng.uniform([-2, -1, 2], [2, 1, 6], size=(1500, 3))
    found = segment(np.concatenate([floor, clutter]))
    assert found.floor is not None
    assert math.degrees(math.acos(min(1.0, found.up @ up))) < 1.0
    assert abs(found.floor.distance(np.zeros((1, 3)))[0] - 1.4) < 0.02  # the camera's height


def test_ransac_keeps_only_accepted_normals():
    rng = np.random.default_rng(2)
    wall = np.c_[rng.uniform(-2, 2, 3000), rng.uniform(-2, 0.5, 3000), np.full(3000, 5.0)]  # z = 5
    floor = np.c_[rng.uniform(-2, 2, 500), np.full(500, 1.0), rng.uniform(1, 5, 500)]
    points = np.concatenate([wall, floor])  # the wall is the larger plane, and not accepted
    found = ransac_plane(points, rng, 0.02, lambda n: np.abs(n[:, 1]) > 0.9)
    assert found is not None
    plane, inliers = found
    assert abs(plane.normal[1]) > 0.99 and inliers[-500:].all() and not inliers[:3000].any()
    assert ransac_plane(points, rng, 0.02, lambda n: np.zeros(len(n), bool)) is None


def test_two_boxes_on_a_floor_are_two_objects_with_their_own_points(two_boxes):
    scene = from_depth(two_boxes.depth, two_boxes.intrinsics)
    found = segment(scene.points)
    assert len(found.objects) == 2
    assert len(found.walls) >= 1
    labels = two_boxes.labels.ravel()[scene.indices]
    owners = sorted(int(np.bincount(labels[rows]).argmax()) for rows in found.objects)
    assert owners == [1, 2]
    for rows in found.objects:
        k = int(np.bincount(labels[rows]).argmax())
        mine = np.flatnonzero(labels == k)
        assert (labels[rows] == k).all()  # nothing of the floor, the wall or the other box
        # all of the box but its lowest centimetres, which the floor's threshold takes
        assert len(rows) >= 0.85 * len(mine)


def test_an_empty_floor_before_a_wall_has_no_objects(empty_scene):
    scene = from_depth(empty_scene.depth, empty_scene.intrinsics)
    found = segment(scene.points)
    assert found.floor is not None and found.objects == []


def test_no_floor_no_objects():
    rng = np.random.default_rng(3)
    assert segment(rng.normal(size=(500, 3)) + np.array([0.0, 0.0, 3.0])).objects == []


def test_a_chair_cut_off_by_a_level_camera_still_stands(level_chair_scene):
    """A level camera 1.7 m up sees the floor only from about 4 m on: a chair 2.2 m away shows
    its upper part alone, and is an object all the same."""
    scene = level_chair_scene
    given = from_depth(scene.depth, scene.intrinsics)
    labels = scene.labels.ravel()[given.indices]
    found = segment(given.points)
    assert found.floor is not None
    assert len(found.objects) == 1
    assert (labels[found.objects[0]] == 1).mean() > 0.95
    assert len(found.objects[0]) > 0.8 * (labels == 1).sum()


def test_a_wide_flat_piece_of_furniture_is_not_a_wall():
    """A board 2.8 m wide and 1.1 m tall (a sideboard, a headboard) is as wide as a wall, but
    the room is seen behind it: it is an object, and the box standing behind it is found too
    (taken for a wall, everything behind its plane would be dropped)."""
    board = boxes_shape([((0, 0, 0), (2.8, 1.1, 0.12))], points=4096)
    box = boxes_shape([((0, 0, 0), (0.5, 0.6, 0.4))])
    scene = make_test_scene([(board, 1.5, -0.3, 3.0, 0.0), (box, 0.4, 1.6, 4.6, 25.0)])
    given = from_depth(scene.depth, scene.intrinsics)
    labels = scene.labels.ravel()[given.indices]
    found = segment(given.points)
    assert len(found.walls) >= 1
    assert all(abs(wall.offset - 6.0) < 0.3 for wall in found.walls)  # only the room's wall
    owners = sorted(int(np.bincount(labels[rows]).argmax()) for rows in found.objects)
    assert owners == [1, 2]


def test_a_panel_a_gap_away_from_its_body_is_one_object():
    """A cabinet whose side panel stands a few centimetres off its body (a gap the clusters do
    not bridge) is one object: the panel, a fifth of its points, joins it. Without the rule
    (``sliver_m=0``) it is a second, false object."""
    from itnet.scene.segment import SegmentOptions

    cabinet = boxes_shape(
        [((0, 0, 0), (0.6, 0.9, 0.5)), ((0.435, 0, 0), (0.03, 0.9, 0.5))], points=3000
    )
    for yaw in (0.0, -30.0):
        scene = make_test_scene([(cabinet, 1.0, 0.0, 2.8, yaw)])
        given = from_depth(scene.depth, scene.intrinsics)
        whole = segment(given.points).objects
        assert len(whole) == 1 and len(whole[0]) > 0.9 * (scene.labels == 1).sum()
        apart = segment(given.points, SegmentOptions(sliver_m=0.0, far_sliver_m=0.0)).objects
        assert len(apart) == 2 and min(map(len, apart)) < 0.3 * max(map(len, apart))


def test_a_thin_panel_farther_off_joins_only_when_small_enough():
    """A cabinet's side panel 15 cm off its body (beyond ``sliver_m``, within ``far_sliver_m``)
    with a tenth of its points joins it; where the far rule asks for a smaller share than the
    panel has, it stays a second, false object."""
    from itnet.scene.segment import SegmentOptions

    cabinet = boxes_shape(
        [((0, 0, 0), (0.6, 0.9, 0.5)), ((0.465, 0, 0), (0.03, 0.9, 0.5))], points=3000
    )
    scene = make_test_scene([(cabinet, 1.0, 0.0, 2.8, -30.0)])
    given = from_depth(scene.depth, scene.intrinsics)
    whole = segment(given.points).objects
    assert len(whole) == 1 and len(whole[0]) > 0.9 * (scene.labels == 1).sum()
    for options in (SegmentOptions(far_sliver_m=0.0), SegmentOptions(far_sliver_share=0.01)):
        apart = segment(given.points, options).objects
        assert len(apart) == 2 and min(map(len, apart)) < 0.2 * max(map(len, apart))


def _block(
    x: tuple[float, float], y: tuple[float, float], z: tuple[float, float], step: float = 0.03
) -> np.ndarray:
    """The points (N, 3) of a block's outside on a grid of ``step`` (y up)."""
    axes = [np.arange(lo, hi + 1e-9, step) for lo, hi in (x, y, z)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    lo, hi = np.array([x[0], y[0], z[0]]), np.array([x[1], y[1], z[1]])
    return grid[np.any((grid - lo < step / 2) | (hi - grid < step / 2), axis=1)]


def test_a_piece_farther_off_joins_only_from_within_its_objects_footprint():
    """15 cm off a large object and with a tenth of its points: a panel along its edge joins
    it, a chest 1 m wide standing beside it does not (a dresser beside a bed is an object of its
    own). Without the footprint rule (``far_sliver_within=0``) the chest joins it too."""
    from itnet.scene.segment import SegmentOptions, slivers_joined

    bed = _block((-1.0, 1.0), (0.0, 0.6), (0.0, 2.0), 0.02)
    panel = _block((1.15, 1.17), (0.0, 0.55), (0.1, 1.9))
    chest = _block((1.15, 2.15), (0.0, 0.6), (0.5, 0.95))
    points = np.concatenate([bed, panel, chest])
    bounds = np.cumsum([0, len(bed), len(panel), len(chest)])
    groups = [np.arange(bounds[k], bounds[k + 1]) for k in range(3)]
    assert max(len(panel), len(chest)) < 0.2 * len(bed)
    up = np.array([0.0, 1.0, 0.0])

    def owners(options: SegmentOptions) -> list[list[int]]:
        joined = slivers_joined(points, groups, options, heights=points[:, 1], up=up)
        return sorted(sorted({int(np.searchsorted(bounds, i, "right")) - 1 for i in g})
                      for g in joined)  # fmt: skip

    assert owners(SegmentOptions()) == [[0, 1], [2]]
    assert owners(SegmentOptions(far_sliver_within=0.0)) == [[0, 1, 2]]


def test_a_small_object_beside_a_large_one_stays_its_own():
    """A small box 0.12 m beside a large one (a fifth of its points) is not a piece of it."""
    big = boxes_shape([((0, 0, 0), (1.0, 0.8, 0.6))], points=3000)
    small = boxes_shape([((0, 0, 0), (0.3, 0.35, 0.3))])
    scene = make_test_scene([(big, 0.9, -0.3, 3.0, 0.0), (small, 0.4, 0.75, 3.0, 0.0)])
    given = from_depth(scene.depth, scene.intrinsics)
    labels = scene.labels.ravel()[given.indices]
    found = segment(given.points)
    owners = sorted(int(np.bincount(labels[rows]).argmax()) for rows in found.objects)
    assert owners == [1, 2]
    sizes = sorted(len(rows) for rows in found.objects)
    assert sizes[0] < 0.3 * sizes[1]  # small enough to be a sliver, and far enough not to be


def test_touching_scenes_stand_each_object_against_another():
    """``make_scene(touching=True)``: two or three objects, each within 1-5 cm of another on the
    floor (their points' footprints), none nearer than 1 cm to any."""
    from itnet.geometry import invert_rigid
    from itnet.model.scenes import SIZES, make_scene

    shapes = {name: [boxes_shape([((0, 0, 0), (0.6, 0.8, 0.5))], seed=k)]
              for k, name in enumerate(SIZES)}  # fmt: skip
    rng = np.random.default_rng(4)
    for _ in range(5):
        scene = make_scene(shapes, rng, touching=True)
        assert 2 <= len(scene.objects) <= 3
        up = invert_rigid(scene.objects[0].pose)[:3, 1]  # canonical +y: the floor's normal
        feet = []
        for truth in scene.objects:
            points = shapes[truth.category][0].points * truth.radius
            camera = points @ invert_rigid(truth.pose)[:3, :3].T + invert_rigid(truth.pose)[:3, 3]
            feet.append(camera - np.outer(camera @ up, up))
        for i, mine in enumerate(feet):
            gaps = [
                float(np.linalg.norm(mine[:, None] - other[None], axis=2).min())
                for j, other in enumerate(feet)
                if j != i
            ]
            assert min(gaps) >= 0.0099 and min(gaps) <= 0.0501


def test_scenes_hold_only_the_categories_asked_for():
    """``make_scene``'s objects come from ``categories``: the eight by default, desks too with
    ``WITH_DESKS``."""
    from itnet.model.scenes import DEVELOPMENT, SIZES, WITH_DESKS, make_scene

    shapes = {name: [boxes_shape([((0, 0, 0), (0.6, 0.8, 0.5))], seed=k)]
              for k, name in enumerate(SIZES)}  # fmt: skip
    rng = np.random.default_rng(2)
    drawn = {o.category for _ in range(12) for o in make_scene(shapes, rng).objects}
    assert drawn <= set(DEVELOPMENT) and "desk" not in drawn
    with_desks = {o.category for _ in range(12)
                  for o in make_scene(shapes, rng, categories=WITH_DESKS).objects}  # fmt: skip
    assert with_desks <= set(WITH_DESKS)
    only = {
        o.category for _ in range(4) for o in make_scene(shapes, rng, categories=("desk",)).objects
    }
    assert only == {"desk"}


def test_scenes_of_a_level_camera_and_at_most_so_many_objects():
    """``pitch_deg=(0, 0)``: the camera looks level (the truth's up lies within its 3 degrees
    of roll of the image's -y); ``most``: no scene holds more objects."""
    from itnet.geometry import invert_rigid
    from itnet.model.scenes import SIZES, make_scene

    shapes = {name: [boxes_shape([((0, 0, 0), (0.6, 0.8, 0.5))], seed=k)]
              for k, name in enumerate(SIZES)}  # fmt: skip
    rng = np.random.default_rng(4)
    counts = []
    for _ in range(8):
        scene = make_scene(shapes, rng, pitch_deg=(0.0, 0.0), most=2)
        counts.append(len(scene.objects))
        for truth in scene.objects:
            up = invert_rigid(truth.pose)[:3, 1]  # the canonical up in the camera frame
            assert abs(up[2]) < 1e-9  # no pitch: up is normal to the optical axis
            assert up[1] < -math.cos(math.radians(3.01))
    assert max(counts) == 2 and min(counts) >= 1


def test_a_level_camera_finds_the_floor_whatever_the_seed():
    """A level camera 1.7 m up sees the floor only from about 4 m on, a band at the bottom of
    its view between the chairs' feet and the wall: the floor's normal is up within a degree
    for every seed of the search, not a plane tilted through the floor's and the wall's edge."""
    from itnet.scene.segment import SegmentOptions

    scene = make_test_scene(
        [(chair_shape(), 0.5, -0.6, 4.5, 30.0), (chair_shape(), 0.5, 0.8, 4.2, 120.0)],
        camera_height=1.7,
        pitch_deg=0.0,
    )
    points = from_depth(scene.depth, scene.intrinsics).points
    options = SegmentOptions(split_touching=False)
    for seed in range(10):
        found = segment(points, options, seed=seed)
        assert found.floor is not None
        assert math.degrees(math.acos(min(1.0, found.up @ np.array([0.0, -1.0, 0.0])))) < 1.0
        assert abs(found.floor.offset - 1.7) < 0.02


def test_ransac_finds_a_plane_that_is_a_small_part_of_the_cloud_from_neighbours():
    """A floor of 150 points among 4,000 scattered ones: three points drawn anywhere rarely
    all lie on it, three neighbours often do."""
    rng = np.random.default_rng(5)
    floor = np.c_[rng.uniform(-1, 1, 150), np.full(150, 1.2), rng.uniform(3, 4, 150)]
    clutter = rng.uniform([-2, -1, 2], [2, 1.2, 6], size=(4000, 3))
    points = np.concatenate([clutter, floor])
    level = lambda n: np.abs(n[:, 1]) > 0.7  # noqa: E731
    found = ransac_plane(points, np.random.default_rng(0), 0.02, level, 2000, local=1000)
    assert found is not None
    plane, inliers = found
    assert abs(plane.normal[1]) > 0.999 and inliers[-150:].mean() > 0.95
    missed = [ransac_plane(points, np.random.default_rng(s), 0.02, level, 200) for s in range(5)]
    assert any(m is None or abs(m[0].normal[1]) < 0.999 for m in missed)


def test_a_floor_is_the_plane_with_nothing_below_it():
    """A table top larger than the floor seen around it: counting the points below each plane
    against it, the floor wins; counting inliers alone, the top does."""
    rng = np.random.default_rng(6)
    top = np.c_[rng.uniform(-1, 1, 3000), np.full(3000, 0.8), rng.uniform(2, 3.5, 3000)]
    floor = np.c_[rng.uniform(-2, 2, 1500), np.full(1500, 1.5), rng.uniform(2, 6, 1500)]
    legs = np.c_[
        rng.choice([-0.95, 0.95], 800), rng.uniform(0.8, 1.5, 800), rng.uniform(2, 3.5, 800)
    ]
    points = np.concatenate([top, floor, legs])  # y down: the floor 1.5 m below the camera
    level = lambda n: np.abs(n[:, 1]) > 0.9  # noqa: E731
    plane, _ = ransac_plane(points, np.random.default_rng(0), 0.02, level, 500, beyond_m=0.1)
    assert abs(abs(plane.offset) - 1.5) < 0.01
    plane, _ = ransac_plane(points, np.random.default_rng(0), 0.02, level, 500)
    assert abs(abs(plane.offset) - 0.8) < 0.01


def test_a_steep_camera_s_strip_of_wall_is_a_wall_not_an_object():
    """A camera 1.4 m up pitched 35 degrees down sees a wall 2 m ahead only up to about 1 m,
    and 2.3 m of its width: smaller than the wall rule's size, but seen up to the top of the
    view, so it is a wall, and the chair before it the only object."""
    from itnet.scene.segment import SegmentOptions

    scene = make_test_scene([(chair_shape(), 0.5, 0.0, 1.3, 160.0)], pitch_deg=35.0, wall_m=2.0)
    given = from_depth(scene.depth, scene.intrinsics)
    labels = scene.labels.ravel()[given.indices]
    found = segment(given.points, SegmentOptions(split_touching=False))
    assert len(found.walls) == 1 and abs(found.walls[0].normal @ found.up) < 0.05
    assert len(found.objects) == 1 and (labels[found.objects[0]] == 1).mean() > 0.95
    blind = segment(given.points, SegmentOptions(split_touching=False, wall_view_top_deg=-90.0))
    assert len(blind.objects) == 2  # without the rule the strip of wall is an object


def test_what_hangs_on_a_wall_does_not_join_the_furniture_against_it():
    """Two cabinets 1 m apart with their backs 2 cm from a wall, and a picture frame hung on the
    wall across both, just above them: two objects, each one cabinet (the frame, within the
    wall's band, links neither to the other). Without the band they are one."""
    from itnet.model.scenes import render, world_from_camera
    from itnet.scene import Intrinsics
    from itnet.scene.segment import SegmentOptions

    cabinet = boxes_shape([((0, 0, 0), (0.6, 0.9, 0.5))], points=3000)
    frame = boxes_shape([((0, 0, 0), (2.0, 0.5, 0.04))], points=3000, seed=1)
    placed = []
    for shape, x, y, z in ((cabinet, -0.8, 0.45, 3.5), (cabinet, 0.8, 0.45, 3.5),
                           (frame, 0.0, 1.12, 3.75)):  # fmt: skip
        world = np.eye(4)
        world[:3, 3] = [x, y, z]
        scale = float(np.ptp(shape.points[:, 1]))  # unit shapes: metres per unit
        placed.append((shape, (0.9 if shape is cabinet else 0.5) / scale, world))
    intrinsics = Intrinsics.from_fov(320, 240, 60.0)
    depth, labels = render(placed, world_from_camera(1.4, 15.0, 0.0), (np.array([0, 0, -1.0]), 3.77),
                           intrinsics, 320, 240, np.random.default_rng(0))  # fmt: skip
    given = from_depth(depth, intrinsics)
    owner = labels.ravel()[given.indices]
    for options, count in ((SegmentOptions(), 2), (SegmentOptions(wall_band_m=0.0), 1)):
        found = segment(given.points, options)
        cabinets = [rows for rows in found.objects if np.isin(owner[rows], (1, 2)).mean() > 0.5]
        assert len(cabinets) == count
        if count == 2:
            assert sorted(int(np.bincount(owner[rows]).argmax()) for rows in cabinets) == [1, 2]


def test_scenes_against_a_wall_stand_their_farthest_object_at_it():
    """``make_scene(against_wall=True)``: the wall the segmentation finds lies within a few
    centimetres of some object's points, and what hangs on it is labelled wall (0)."""
    from itnet.geometry import invert_rigid
    from itnet.model.scenes import SIZES, make_scene

    shapes = {name: [boxes_shape([((0, 0, 0), (0.6, 0.8, 0.5))], seed=k)]
              for k, name in enumerate(SIZES)}  # fmt: skip
    rng = np.random.default_rng(5)
    for _ in range(4):
        scene = make_scene(shapes, rng, against_wall=True)
        assert scene.labels.max() <= len(scene.objects)
        walls = segment(from_depth(scene.depth, scene.intrinsics).points).walls
        gaps = []
        for truth in scene.objects:
            to_camera = invert_rigid(truth.pose)
            points = shapes[truth.category][0].points * truth.radius
            points = points @ to_camera[:3, :3].T + to_camera[:3, 3]
            gaps += [float(np.abs(wall.distance(points)).min()) for wall in walls]
        assert gaps and min(gaps) < 0.07


def test_an_object_whose_base_another_hides_stands_on_the_floor_the_camera_does_not_see():
    """A headboard-like board 0.85 m behind a low, wide box (a bed's foot, an ottoman) is seen
    only from 0.7 m up: it floats, and no object lies within ``attach_m`` of it. The floor under
    it is hidden by the box, so it stands; where pieces on a hidden floor must be larger than
    it is, it is dropped."""
    from itnet.scene.segment import SegmentOptions

    front = boxes_shape([((0, 0, 0), (1.6, 0.9, 0.5))], points=3000)
    board = boxes_shape([((0, 0, 0), (1.6, 1.5, 0.1))], points=3000, seed=1)
    scene = make_test_scene([(front, 0.951, 0.0, 2.5, 0.0), (board, 1.098, 0.0, 3.65, 0.0)])
    given = from_depth(scene.depth, scene.intrinsics)
    labels = scene.labels.ravel()[given.indices]
    found = segment(given.points)
    assert sorted(int(np.bincount(labels[rows]).argmax()) for rows in found.objects) == [1, 2]
    dropped = segment(given.points, SegmentOptions(hidden_min_points=100_000))
    assert sorted(int(np.bincount(labels[rows]).argmax()) for rows in dropped.objects) == [1]
