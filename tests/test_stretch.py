"""Stretched shapes: more shapes than a category has, in the same frame and pose."""

import numpy as np
import pytest

from itnet.geometry import apply_rigid
from itnet.model.scanner import scan_config
from itnet.model.shapes import Shape, random_stretch, stretched, to_canonical
from itnet.model.surface import surface_discs

QUIET = {"depth_noise": (0.0, 0.0), "jitter": (0.0, 0.0), "outlier_fraction": (0.0, 0.0)}


def box_surface(rng: np.random.Generator, n: int, half: tuple[float, float, float]) -> np.ndarray:
    """n points (n, 3) on the surface of an axis-aligned box with these half extents."""
    p = rng.uniform(-1, 1, size=(n, 3))
    axis = rng.integers(3, size=n)
    p[np.arange(n), axis] = rng.choice([-1.0, 1.0], size=n)
    return p * half


def test_a_stretched_shape_is_a_unit_shape_in_the_same_frame():
    rng = np.random.default_rng(0)
    points, _ = to_canonical(box_surface(rng, 3000, (1.0, 1.0, 1.0)), "canonical")
    triangles = np.array([[0, 1, 2]])
    shape = Shape("cube", points, triangles)
    wide = stretched(shape, np.array([2.0, 1.0, 0.5]))
    half = np.abs(wide.points).max(0)
    assert half[0] / half[1] == pytest.approx(2.0, rel=1e-6)
    assert half[2] / half[1] == pytest.approx(0.5, rel=1e-6)
    assert np.allclose((wide.points.min(0) + wide.points.max(0)) / 2, 0.0, atol=1e-9)
    assert np.linalg.norm(wide.points, axis=1).max() == pytest.approx(1.0)
    assert wide.triangles is triangles and wide.name == "cube"
    assert np.array_equal(stretched(shape, np.ones(3)).points, shape.points)
    assert shape.points is points  # the original is untouched


@pytest.mark.parametrize("factors", [(1.0, 2.0), (1.0, 0.0, 1.0), (1.0, -1.0, 1.0)])
def test_bad_stretch_factors_are_refused(factors):
    shape = Shape("ball", np.random.default_rng(0).normal(size=(50, 3)))
    with pytest.raises(ValueError, match="3 positive numbers"):
        stretched(shape, np.array(factors))


def test_random_factors_stay_in_their_range():
    f = np.stack([random_stretch(np.random.default_rng(i), 1.25) for i in range(500)])
    assert f.shape == (500, 3) and f.min() >= 1 / 1.25 and f.max() <= 1.25
    assert f.min() < 0.82 and f.max() > 1.22  # the range is used
    assert np.array_equal(random_stretch(np.random.default_rng(0), 1.0), np.ones(3))


def test_surface_discs_carry_over_as_if_computed_on_the_stretched_points():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(1500, 3))
    ball = Shape("ball", p / np.linalg.norm(p, axis=1, keepdims=True))
    ball.discs()
    egg = stretched(ball, np.array([2.0, 1.0, 0.5]))
    assert egg._discs is not None  # carried, not recomputed
    normals, spacing = egg._discs
    fresh_normals, fresh_spacing = surface_discs(egg.points)
    assert np.abs((normals * fresh_normals).sum(1)).mean() > 0.98
    assert np.median(spacing / fresh_spacing) == pytest.approx(1.0, abs=0.05)
    assert stretched(Shape("ball", ball.points), np.ones(3))._discs is None  # lazily, as usual


@pytest.mark.parametrize("rule", [{}, {"splat": 1.0, "tolerance": 0.03}])
def test_pose_batches_of_stretched_shapes_keep_their_poses(rule):
    """Views of a stretched cube, moved by their target poses (into the canonical frame at the
    view's normalised scale), lie on an axis-aligned box about the origin (a wrong pose would
    turn it); the cube's views are cubes, the stretched ones are not."""
    from itnet.model.data import training_batch

    rng = np.random.default_rng(2)
    cube = Shape("cube", to_canonical(box_surface(rng, 4000, (1.0, 1.0, 1.0)), "canonical")[0])
    config = scan_config(QUIET, rule)
    aspect = []
    for stretch in (1.0, 1.5):
        x, target = training_batch(
            [cube], 12, 512, np.random.default_rng(3), config, stretch=stretch
        )
        for view, pose in zip(x, target):
            canonical = apply_rigid(pose.astype(np.float64), view.astype(np.float64))
            half = np.abs(canonical).max(0)
            on_a_face = (np.abs(canonical) >= half - 0.03).any(1)
            assert on_a_face.mean() > 0.95, on_a_face.mean()
            aspect.append((stretch, half.max() / half.min()))
    assert all(ratio < 1.03 for s, ratio in aspect if s == 1.0)
    assert max(ratio for s, ratio in aspect if s > 1) > 1.3


def test_classifier_batches_stretch_only_when_asked():
    from itnet.model.classify.data import LabelledShapes, training_batch

    rng = np.random.default_rng(4)
    shapes = [Shape(f"box{i}", to_canonical(box_surface(rng, 800, (1, 2, 3)), "canonical")[0])
              for i in range(3)]  # fmt: skip
    data = LabelledShapes(shapes, np.array([0, 1, 2]))
    configs = [scan_config(QUIET)]

    def batch(stretch: float | None, seed: int = 5):
        extra = {} if stretch is None else {"stretch": stretch}
        return training_batch(data, 6, 64, np.random.default_rng(seed), configs, **extra)

    plain, same, stretched_views = batch(None), batch(1.0), batch(1.3)
    assert all(np.array_equal(a, b) for a, b in zip(plain, same))  # off: the same stream
    assert np.array_equal(plain[1], stretched_views[1])  # the same shapes drawn
    assert not np.allclose(plain[0], stretched_views[0])
    assert all(np.array_equal(a, b) for a, b in zip(stretched_views, batch(1.3)))  # seeded
