"""A scene segmented on a working cloud whose size follows the room and the budget, not the
camera's resolution; objects no category fits answered as unknown; a low object alone on the
floor kept; a wall with a window still a wall."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scene_helpers import boxes_shape, chair_shape, make_test_scene

from itnet.pose.request import PoseRequest
from itnet.scene import SceneFinishing, find_objects
from itnet.scene.inputs import from_depth
from itnet.scene.segment import SegmentOptions, VoxelCloud, segment, working_points
from itnet.scene.unknown import TOO_LARGE, TOO_TALL_M, cluster_radius, unknown_reason
from itnet.scene.warm_up import warm_up


def test_the_working_cloud_follows_the_room_not_the_resolution() -> None:
    """The same scene at 320x240 and 1280x720: about as many working voxels either way (never
    more than asked), the same objects found, each with every point of its voxels at the
    camera's resolution (far more points than voxels at 1280x720)."""
    chair = chair_shape()
    sizes = {}
    for width, height in ((320, 240), (1280, 720)):
        scene = make_test_scene([(chair, 0.5, -0.6, 3.0, 160.0), (chair, 0.5, 0.8, 3.4, 20.0)],
                                width=width, height=height)  # fmt: skip
        given = from_depth(scene.depth, scene.intrinsics)
        cloud = VoxelCloud.of(given.points, 0.03, 6000)
        assert len(cloud.points) <= 6000
        work = cloud.points
        found = segment(given.points, SegmentOptions(work_points=6000))
        labels = scene.labels.ravel()[given.indices]
        assert len(found.objects) == 2
        assert sorted(np.bincount(labels[o]).argmax() for o in found.objects) == [1, 2]
        sizes[width] = (len(work), [len(o) for o in found.objects])
    (small_work, small), (large_work, large) = sizes[320], sizes[1280]
    assert 0.5 < large_work / small_work < 2.0
    assert all(b > 8 * a for a, b in zip(sorted(small), sorted(large), strict=True))


def test_the_working_cloud_grows_with_the_budget_up_to_its_bound() -> None:
    assert working_points(50) < working_points(100) < working_points(140)
    assert working_points(1) == working_points(2)
    assert working_points(140) == working_points(250) == working_points(1e5)


def test_a_cluster_too_large_for_its_category_is_unknown() -> None:
    """A 4.8 m long block is larger than any real bed, table or sofa: whatever names it, it is
    unknown; a chair-sized cluster named chair with even odds stands; a name below even odds is
    unsure."""
    rng = np.random.default_rng(0)
    up = np.array([0.0, -1.0, 0.0])
    block = rng.uniform([-2.4, -1.2, 3.0], [2.4, 0.0, 3.6], size=(4000, 3))
    assert cluster_radius(block, up) > TOO_LARGE * 1.6
    for name in ("bed", "sofa", "table", "chair"):
        assert unknown_reason(name, 0.9, block, up) == "too_large"
    seat = rng.uniform([-0.25, -0.9, 3.0], [0.25, 0.0, 3.5], size=(2000, 3))
    assert unknown_reason("chair", 0.9, seat, up) is None
    assert unknown_reason("chair", 0.35, seat, up) == "unsure"
    assert unknown_reason("my_cabinet", 0.9, block, up) is None  # no real sizes: never too large


def test_a_cluster_taller_than_any_category_is_unknown_where_its_top_is_known() -> None:
    """A curtain-like panel 0.6 m across whose top stands 2.8 m over the floor: its radius alone
    passes for a sofa, its height does not; with no floor (no height given) it stands; a
    dresser with a mirror on it (1.6 m) stands."""
    rng = np.random.default_rng(1)
    up = np.array([0.0, -1.0, 0.0])
    panel = rng.uniform([-0.3, -2.8, 3.0], [0.3, -1.3, 3.05], size=(3000, 3))
    assert cluster_radius(panel, up) < TOO_LARGE * 1.45
    assert unknown_reason("sofa", 0.9, panel, up) is None
    assert unknown_reason("sofa", 0.9, panel, up, top_m=2.8) == "too_large"
    assert unknown_reason("sofa", 0.9, panel, up, top_m=TOO_TALL_M - 0.1) is None
    dresser = rng.uniform([-0.6, -1.6, 3.0], [0.6, 0.0, 3.5], size=(3000, 3))
    assert unknown_reason("dresser", 0.9, dresser, up, top_m=1.6) is None
    assert unknown_reason("my_cabinet", 0.9, panel, up, top_m=2.8) is None  # no real sizes


def test_a_block_too_large_for_any_category_is_answered_unknown_not_dropped() -> None:
    """A 4 m block: left whole, it is unknown (too large), with its box and points; with the
    recognition's split it may be parted, but never answered as one object of a category too
    small for it; with unknown objects off it is named."""
    block = boxes_shape([((0, 0, 0), (4.0, 1.1, 0.6))], points=8000)
    radius = 0.5 * float(np.linalg.norm([4.0, 1.1, 0.6]))
    scene = make_test_scene([(block, radius, 0.0, 4.0, 0.0), (chair_shape(), 0.5, -1.5, 2.6, 160.0)],
                            wall_m=7.0)  # fmt: skip
    given = from_depth(scene.depth, scene.intrinsics)
    labels = scene.labels.ravel()

    warm_up()  # the models loaded: the budget is the scene's

    def answered(finishing: SceneFinishing) -> dict[int, list]:
        result = find_objects(scene.depth, scene.intrinsics, budget_ms=400, finishing=finishing)
        out: dict[int, list] = {}
        for o in result.objects:
            out.setdefault(int(np.bincount(labels[o.indices]).argmax()), []).append(o)
        return out

    whole = answered(SceneFinishing(named_split=False))
    (block_answer,) = whole[1]
    assert block_answer.category is None and block_answer.unknown == "too_large"
    assert block_answer.pose is None and block_answer.as_dict()["no_pose"] == "unknown"
    assert len(block_answer.indices) > 0.5 * (labels[given.indices] == 1).sum()
    assert whole[2][0].category is not None and whole[2][0].unknown is None
    up = np.array([0.0, -1.0, 0.0])
    for part in answered(SceneFinishing())[1]:
        points = given.points[np.searchsorted(given.indices, part.indices)]
        assert part.category is None or unknown_reason(part.category, 1.0, points, up) is None
    assert all(o.category is not None for o in answered(SceneFinishing(unknown=False))[1])


def test_a_low_wide_object_alone_on_the_floor_is_found() -> None:
    """A tub 0.9 m long and 0.3 m high stays below the height of a standing object: with no
    object near it to belong to, it is an object of its own, not dropped."""
    tub = boxes_shape([((0, 0, 0), (0.9, 0.3, 0.5))], points=6000)
    radius = 0.5 * float(np.linalg.norm([0.9, 0.3, 0.5]))
    scene = make_test_scene([(tub, radius, 0.0, 2.4, 30.0)], wall_m=3.5)
    given = from_depth(scene.depth, scene.intrinsics)
    found = segment(given.points)
    labels = scene.labels.ravel()[given.indices]
    assert len(found.objects) == 1 and (labels[found.objects[0]] == 1).mean() > 0.9
    assert (labels[found.objects[0]] == 1).sum() > 0.8 * (labels == 1).sum()


def test_a_wall_with_a_window_is_a_wall() -> None:
    """A wall 4 m ahead with a window through which another wall 2 m beyond it is seen: what is
    seen through it is a small share of what is seen on or through the wall, so it is still a
    wall, and the chair before it the only object."""
    scene = make_test_scene([(chair_shape(), 0.5, 0.4, 2.6, 160.0)], wall_m=4.0, pitch_deg=10.0)
    depth = scene.depth.copy()
    h, w = depth.shape
    window = np.zeros_like(depth, dtype=bool)
    window[int(0.1 * h) : int(0.35 * h), int(0.15 * w) : int(0.45 * w)] = True
    window &= scene.labels == 0
    depth[window] *= 1.5  # seen through the window: the room behind, half as far again
    given = from_depth(depth, scene.intrinsics)
    found = segment(given.points)
    labels = scene.labels.ravel()[given.indices]
    assert len(found.walls) >= 1
    assert len(found.objects) == 1 and (labels[found.objects[0]] == 1).mean() > 0.9


def test_the_recognition_parts_a_cluster_where_both_parts_are_objects(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two boxes 3 cm apart along x make one cluster: of the cut judge's planes, the one through
    the gap leaves two parts that a category fits (here: any part narrower than 1 m), and the
    cluster is parted there; where no part fits, it stays whole."""
    from itnet.planes import Plane
    from itnet.scene import named_split

    rng = np.random.default_rng(3)
    left = rng.uniform([-0.83, -0.8, 3.0], [-0.03, 0.0, 3.5], size=(3000, 3))
    right = rng.uniform([0.0, -0.7, 3.0], [0.8, 0.0, 3.5], size=(3000, 3))
    points = np.concatenate([left, right])
    floor = Plane(np.array([0.0, -1.0, 0.0]), 0.0)  # y down: the floor at y = 0
    namer = named_split.Namer(None, None, None, floor, np.zeros(3))  # type: ignore[arg-type]

    def narrow(self: object, part: np.ndarray, deadline: float) -> float | None:
        return 0.9 if np.ptp(part[:, 0]) < 1.0 else None

    monkeypatch.setattr(named_split.Namer, "confidence", narrow)
    parts = named_split.named_parts(points, namer, None, time.perf_counter() + 10)
    assert sorted(len(p) for p in parts) == [3000, 3000]
    assert {frozenset(p.tolist()) for p in parts} == {frozenset(range(3000)),
                                                      frozenset(range(3000, 6000))}  # fmt: skip
    monkeypatch.setattr(named_split.Namer, "confidence", lambda self, part, deadline: None)
    (whole,) = named_split.named_parts(points, namer, None, time.perf_counter() + 10)
    assert len(whole) == 6000


@pytest.mark.timing
def test_every_object_of_a_usual_frame_is_posed_within_the_default_budget() -> None:
    """Four chairs apart at 640x480: the reply comes within the default budget (the clock
    started before the frame is read, a little scheduling slack), and every chair found comes
    back with a pose; each object's pose ends early enough for its finishing steps."""
    from itnet.scene.pipeline import DEFAULT_BUDGET_MS

    warm_up()
    chair = chair_shape()
    scene = make_test_scene([(chair, 0.5, -1.6, 3.2, 160.0), (chair, 0.5, -0.5, 3.6, 20.0),
                             (chair, 0.5, 0.6, 3.1, 200.0), (chair, 0.5, 1.7, 3.7, 90.0)],
                            width=640, height=480)  # fmt: skip
    find_objects(scene.depth, scene.intrinsics)
    started = time.perf_counter()
    result = find_objects(scene.depth, scene.intrinsics, started=started)
    took_ms = (time.perf_counter() - started) * 1e3
    assert took_ms <= DEFAULT_BUDGET_MS * 1.04 + 5.0
    assert len(result.objects) == 4
    assert all(o.pose is not None for o in result.objects), [o.no_pose for o in result.objects]


def test_a_scene_objects_runs_each_see_at_most_the_scenes_points(monkeypatch) -> None:
    """A scene's object is posed through ``Catalog.start``, as every path is, by a request that
    says its points per run (SCENE_RUN_POINTS) and no schedule: every run sees at most that."""
    import itnet.pose.catalog as catalog
    import itnet.scene.posing as posing

    seen: list[tuple[tuple[int, ...], PoseRequest]] = []

    class Recorded(catalog.AnytimeRun):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            seen.append((self.points.shape, self.plan.request))

    monkeypatch.setattr(catalog, "AnytimeRun", Recorded)
    warm_up()
    scene = make_test_scene([(chair_shape(), 0.5, 0.0, 2.8, 160.0)], width=640, height=480)
    result = find_objects(scene.depth, scene.intrinsics, budget_ms=1000)
    assert result.objects and result.objects[0].pose is not None
    assert seen and all(shape[1] <= posing.SCENE_RUN_POINTS for shape, _ in seen)
    assert max(shape[1] for shape, _ in seen) == posing.SCENE_RUN_POINTS
    for _, request in seen:
        assert request.points_per_run == posing.SCENE_RUN_POINTS and request.schedule is False
        assert request.up is not None and request.viewpoint is not None


def test_objects_the_budget_has_no_time_left_to_name_come_back_boxed_and_unnamed(two_boxes):
    """The scene's clock started long ago: the segmentation's objects come back at once, each
    with its points and box, unnamed (``unknown: "budget"``, no pose), none dropped."""
    warm_up()
    result = find_objects(two_boxes.depth, two_boxes.intrinsics, budget_ms=100,
                          started=time.perf_counter() - 10.0)  # fmt: skip
    assert len(result.objects) == 2
    for obj in result.objects:
        answer = obj.as_dict()
        assert obj.category is None and answer["unknown"] == "budget"
        assert answer["no_pose"] == "budget" and obj.pose is None
        assert len(obj.indices) > 100 and min(obj.box.size) > 0.2
    fresh = find_objects(two_boxes.depth, two_boxes.intrinsics, budget_ms=1000)
    assert all(o.unknown != "budget" for o in fresh.objects)
