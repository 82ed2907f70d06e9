"""Things of no category: their shapes at real sizes, and scenes that hold them among objects."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from itnet.model.distractors import KINDS, distractor
from itnet.model.scenes import make_scene
from itnet.model.shapes import Shape


@pytest.mark.parametrize("kind", KINDS)
def test_each_thing_is_a_unit_shape_at_a_real_size(kind: str) -> None:
    heights = []
    for seed in range(5):
        shape, metres = distractor(kind, np.random.default_rng(seed))
        centre = (shape.points.min(0) + shape.points.max(0)) / 2
        np.testing.assert_allclose(centre, 0.0, atol=1e-9)
        assert np.linalg.norm(shape.points, axis=1).max() == pytest.approx(1.0)
        heights.append(float(np.ptp(shape.points[:, 1])) * metres)
    low, high = {"ottoman": (0.3, 0.55), "bin": (0.25, 0.8), "lamp": (1.2, 2.1),
                 "plant": (0.3, 2.0), "cabinet": (1.1, 2.1)}[kind]  # fmt: skip
    assert low <= min(heights) and max(heights) <= high
    with pytest.raises(ValueError, match="unknown distractor"):
        distractor("piano", np.random.default_rng(0))


def _shapes() -> dict[str, list[Shape]]:
    rng = np.random.default_rng(0)
    box = rng.uniform(-0.5, 0.5, (1024, 3))
    box /= np.linalg.norm(box, axis=1).max()
    return {name: [Shape(name, box)] for name in ("chair", "table")}


def test_a_scene_holds_things_apart_from_its_objects_which_stay_as_they_were() -> None:
    shapes, seen_others = _shapes(), 0
    for seed in range(6):
        plain = make_scene(shapes, np.random.default_rng(seed), categories=("chair", "table"))
        busy = make_scene(shapes, np.random.default_rng(seed), categories=("chair", "table"),
                          distractors=2)  # fmt: skip
        assert plain.others == [] and len(busy.others) <= 2 and set(busy.others) <= set(KINDS)
        assert [o.category for o in busy.objects] == [o.category for o in plain.objects]
        for a, b in zip(busy.objects, plain.objects, strict=True):
            np.testing.assert_array_equal(a.pose, b.pose)
        count = len(busy.objects)
        assert busy.labels.max() <= count + len(busy.others)
        for j in range(len(busy.others)):
            seen_others += int((busy.labels == count + 1 + j).sum() > 0)
    assert seen_others >= 3  # things in view, labelled after the objects


def test_things_on_top_stand_on_the_objects_as_part_of_them_and_change_nothing_else() -> None:
    shapes, carried = _shapes(), 0
    for seed in range(4):
        kinds = {"categories": ("chair", "table"), "distractors": 1, "against_wall": True}
        plain = make_scene(shapes, np.random.default_rng(seed), **kinds)
        laden = make_scene(shapes, np.random.default_rng(seed), on_top=1.0, **kinds)
        assert laden.others == plain.others
        for a, b in zip(laden.objects, plain.objects, strict=True):
            np.testing.assert_array_equal(a.pose, b.pose)
        count = len(laden.objects)
        gained = (laden.labels >= 1) & (laden.labels <= count) & (laden.labels != plain.labels)
        carried += int(gained.sum())
        for k in range(1, count + 1):  # what an object gained stands above what it had
            rows, _ = np.nonzero(gained & (laden.labels == k))
            had, _ = np.nonzero(plain.labels == k)
            if len(rows) > 20:
                assert rows.mean() < had.mean()  # image rows grow downwards
            assert ((laden.labels == k) & (plain.labels == k)).sum() >= 0.8 * len(had)
    assert carried > 200


def test_the_scenes_benchmark_counts_a_named_thing_false() -> None:
    from benchmarks.bench_scene import match, summary

    shapes = _shapes()
    scene = next(s for seed in range(20)
                 if (s := make_scene(shapes, np.random.default_rng(seed), categories=("chair",),
                                     distractors=1)).others)  # fmt: skip
    thing = np.flatnonzero(scene.labels.ravel() == len(scene.objects) + 1)

    for category, false in (("bathtub", 1), (None, 0)):
        returned = SimpleNamespace(indices=thing, category=category, probability=0.9, pose=None,
                                   unknown=None if category else "not_ours")  # fmt: skip
        rows = match(SimpleNamespace(objects=[returned]), scene, min_pixels=1)  # type: ignore[arg-type]
        assert [r["kind"] for r in rows if r["kind"] == "distractor"] == ["distractor"]
        report = summary(rows, returned=1)
        assert report["false"]["count"] == false
        assert report["distractors_named"] == {"percent": 100.0 * false, "stderr": 0.0,
                                               "count": false, "of": 1}  # fmt: skip


def test_a_scene_seen_by_a_named_camera_loses_far_and_grazing_returns() -> None:
    from itnet.model.scenes import SceneKind

    shapes = _shapes()
    plain = make_scene(shapes, np.random.default_rng(2), categories=("chair",))
    seen = make_scene(shapes, np.random.default_rng(2), categories=("chair",), sensor="kinect_v2")
    np.testing.assert_array_equal(seen.labels, plain.labels)  # the same scene
    assert (seen.depth > 0).mean() < (plain.depth > 0).mean() - 0.05
    assert SceneKind(sensor="kinect_v2").keywords(("chair",))["sensor"] == "kinect_v2"
    with pytest.raises(ValueError, match="unknown camera"):
        SceneKind(sensor="kinect_v9")
