"""A room's cloud (no camera at its origin) as well as a camera's view: the floor found by up
wherever the origin lies, the objects found as in the camera's frame, and the way in decided
from the cloud."""

from __future__ import annotations

import numpy as np
import pytest

from itnet.model.scenes import Scene, world_from_camera
from itnet.scene import from_depth
from itnet.scene.room import looks_like_a_view, segment_scene
from itnet.scene.segment import SegmentOptions, segment

ROOM_FROM_WORLD = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # world y up -> room z up
UP = np.array([0.0, 0.0, 1.0])


def in_a_room(scene: Scene, origin_on_floor: tuple[float, float]) -> np.ndarray:
    """A test scene's camera-frame points moved into a z-up frame whose origin lies on the
    floor at ``origin_on_floor`` (world x, z; the scenes' camera: 1.4 m up, pitched 15 deg)."""
    points = from_depth(scene.depth, scene.intrinsics).points
    camera = world_from_camera(1.4, 15.0, 0.0)
    world = points @ camera[:3, :3].T + camera[:3, 3]
    world -= [origin_on_floor[0], 0.0, origin_on_floor[1]]
    return world @ ROOM_FROM_WORLD.T


def owners(found, labels: np.ndarray) -> list[int]:
    return sorted(int(np.bincount(labels[rows]).argmax()) for rows in found.objects)


def test_a_room_s_cloud_with_its_origin_on_the_floor_has_its_floor_and_objects(two_boxes):
    labels = two_boxes.labels.ravel()[from_depth(two_boxes.depth, two_boxes.intrinsics).indices]
    for origin in ((0.0, 3.1), (-2.0, 1.0)):  # amid the objects; to one side, before them
        points = in_a_room(two_boxes, origin)
        found = segment_scene(points, SegmentOptions(), UP)
        assert found.room and found.edges is None
        assert found.floor is not None and abs(found.floor.offset) < 0.03
        assert abs(found.floor.distance(found.viewpoint[None])[0] - 1.5) < 0.05  # the lookout
        assert found.up @ UP > 0.99
        assert owners(found, labels) == [1, 2]
        # taken for a camera's view, the floor through the origin is no floor
        assert segment(points, SegmentOptions(), UP).objects == []


def test_a_camera_s_view_stays_one(two_boxes):
    points = from_depth(two_boxes.depth, two_boxes.intrinsics).points
    assert looks_like_a_view(points)
    found = segment_scene(points, SegmentOptions(), np.array([0.0, -1.0, 0.0]))
    assert not found.room and np.allclose(found.viewpoint, 0.0)
    labels = two_boxes.labels.ravel()[from_depth(two_boxes.depth, two_boxes.intrinsics).indices]
    assert owners(found, labels) == owners(segment(points), labels) == [1, 2]


def test_asked_for_a_room_a_camera_s_view_is_looked_at_from_above_its_floor(two_boxes):
    points = from_depth(two_boxes.depth, two_boxes.intrinsics).points
    found = segment_scene(points, SegmentOptions(), np.array([0.0, -1.0, 0.0]), room=True)
    assert found.room and found.floor is not None
    assert abs(found.floor.offset - 1.4) < 0.05  # the plane in the cloud's own frame
    labels = two_boxes.labels.ravel()[from_depth(two_boxes.depth, two_boxes.intrinsics).indices]
    # a few of the wall's noisy points may stay a cluster (too few for the classifier: no answer)
    found.objects = [rows for rows in found.objects if len(rows) >= 50]
    assert owners(found, labels) == [1, 2]


def test_a_depth_image_is_a_camera_s_view(two_boxes):
    points = from_depth(two_boxes.depth, two_boxes.intrinsics).points
    with pytest.raises(ValueError, match="depth image"):
        segment_scene(points, SegmentOptions(), np.array([0.0, -1.0, 0.0]), room=True, image=True)


def test_a_view_lies_within_a_cone_and_a_room_all_round():
    rng = np.random.default_rng(0)
    ahead = rng.normal(size=(5000, 3)) * [0.6, 0.4, 0.1] + [0.0, 0.0, 3.0]
    around = rng.normal(size=(5000, 3))
    assert looks_like_a_view(ahead)
    assert not looks_like_a_view(around)
    assert not looks_like_a_view(np.zeros((10, 3)))


def test_a_chair_in_a_room_s_cloud_is_named_and_posed_upright(chair_scene):
    from itnet.scene import find_objects

    points = in_a_room(chair_scene, (0.5, 2.0))
    result = find_objects(points, expected_up=(0.0, 0.0, 1.0), budget_ms=1000)
    assert result.room and result.as_dict()["room"] is True
    assert len(result.objects) == 1 and result.objects[0].category is not None
    pose = result.objects[0].pose
    assert pose is not None
    canonical_up = pose[:3, :3].T[:, 1]  # the canonical +y in the room's frame
    assert canonical_up @ UP > 0.99
    run = result.objects[0].run
    assert run is not None and np.allclose(run["up"], UP, atol=0.02)
    camera = find_objects(from_depth(chair_scene.depth, chair_scene.intrinsics), budget_ms=1000)
    assert not camera.room and camera.as_dict()["room"] is False


def test_a_depth_image_asked_to_be_a_room_s_is_refused_with_a_clear_error(chair_scene):
    from itnet.scene import find_objects
    from itnet.scene.camera import SceneInputError

    with pytest.raises(SceneInputError, match="depth image is one camera's view"):
        find_objects(chair_scene.depth, chair_scene.intrinsics, room=True)


def _plane(rng: np.random.Generator, origin, u, v, extent_u: float, extent_v: float) -> np.ndarray:
    a, b = np.meshgrid(np.arange(0, extent_u, 0.04), np.arange(0, extent_v, 0.04))
    points = np.asarray(origin) + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    return points + rng.normal(scale=0.005, size=points.shape)


def _box(rng: np.random.Generator, centre, size) -> np.ndarray:
    """Points on a box's sides and top (z up), 2 cm apart."""
    faces = []
    for axis in range(3):
        for sign in (-1, 1) if axis < 2 else (1,):
            u, v = [k for k in range(3) if k != axis]
            a, b = np.meshgrid(np.arange(-size[u] / 2, size[u] / 2, 0.02),
                               np.arange(-size[v] / 2, size[v] / 2, 0.02))  # fmt: skip
            face = np.zeros((a.size, 3))
            face[:, u], face[:, v], face[:, axis] = a.ravel(), b.ravel(), sign * size[axis] / 2
            faces.append(face + centre)
    points = np.concatenate(faces)
    return points + rng.normal(scale=0.004, size=points.shape)


def test_a_scanned_room_with_four_walls_and_a_ceiling_has_only_its_furniture(monkeypatch):
    """A room scanned all round (floor, ceiling, four walls; the origin in a corner of the floor,
    z up) with three pieces of furniture, one 2 m tall: a room's, its four walls found, and its
    three objects, each only itself. Without the ceiling left out and walls all round, the
    ceiling and the fourth wall join the furniture or stand as objects."""
    from itnet.scene import room as rooms

    rng = np.random.default_rng(0)
    x, y, z = np.eye(3)
    planes = [_plane(rng, (0, 0, 0), x, y, 5.0, 4.0), _plane(rng, (0, 0, 2.6), x, y, 5.0, 4.0),
              _plane(rng, (0, 0, 0), x, z, 5.0, 2.6), _plane(rng, (0, 4.0, 0), x, z, 5.0, 2.6),
              _plane(rng, (0, 0, 0), y, z, 4.0, 2.6), _plane(rng, (5.0, 0, 0), y, z, 4.0, 2.6)]  # fmt: skip
    boxes = [_box(rng, (1.5, 2.0, 0.4), (0.6, 0.5, 0.8)), _box(rng, (3.5, 2.2, 0.3), (0.9, 0.6, 0.6)),
             _box(rng, (4.6, 3.6, 1.0), (0.7, 0.6, 2.0))]  # fmt: skip
    points = np.concatenate(planes + boxes)
    labels = np.concatenate([np.zeros(sum(map(len, planes)), int)]
                            + [np.full(len(b), k + 1) for k, b in enumerate(boxes)])  # fmt: skip
    found = segment_scene(points, SegmentOptions(), UP)
    assert found.room and len(found.walls) == 4
    assert owners(found, labels) == [1, 2, 3]
    assert all((labels[rows] > 0).mean() > 0.95 for rows in found.objects)
    monkeypatch.setattr(rooms, "CEILING_CUT_M", 100.0)
    monkeypatch.setattr(rooms, "ROOM_WALLS", 3)
    bare = segment_scene(points, SegmentOptions(), UP)
    assert owners(bare, labels) != [1, 2, 3] or any(
        (labels[rows] > 0).mean() < 0.95 for rows in bare.objects
    )
