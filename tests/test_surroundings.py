"""Views cut out of a room: the floor, wall and neighbour a crop keeps beside its object."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from itnet.geometry import apply_rigid
from itnet.model.scanner import (
    CROP_ELEVATION,
    named_views,
    scan_config,
    scan_shape,
    view_name_parts,
)
from itnet.model.surroundings import Surroundings, top_points


def _box_shape(rng: np.random.Generator) -> np.ndarray:
    """A night-stand-like box's surface, 1,024 points, standing on y = -0.6 (unit radius)."""
    half = np.array([0.5, 0.6, 0.4])
    points = rng.uniform(-half, half, (1024, 3))
    face = rng.integers(3, size=1024)
    points[np.arange(1024), face] = np.sign(rng.normal(size=1024)) * half[face]
    return points


def test_a_crop_keeps_floor_wall_and_neighbour_inside_its_grown_box() -> None:
    rng = np.random.default_rng(0)
    shape = _box_shape(rng)
    every = Surroundings(wall=1.0, neighbour=1.0, grow_m=(0.1, 0.1), floor_removed=0.0)
    surrounded, normals, boxed = every.around(shape, spacing=0.07, radius_m=0.5, rng=rng)
    assert boxed == len(shape)  # nothing stands on it by default
    assert len(surrounded) > len(shape) and len(normals) == len(surrounded) - len(shape)
    np.testing.assert_array_equal(surrounded[: len(shape)], shape)  # the shape's rows first
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    added = surrounded[len(shape) :]
    assert (added[:, 1] >= shape[:, 1].min() - 1e-9).all()  # nothing under the floor
    assert np.isclose(added[:, 1], shape[:, 1].min()).sum() > 100  # a floor
    kept = every.crop(surrounded, shape, radius_m=0.5, rng=rng)
    grown = 0.1 / 0.5
    inside = np.all(
        (surrounded >= shape.min(0) - grown - 1e-9) & (surrounded <= shape.max(0) + grown + 1e-9),
        axis=1,
    )
    np.testing.assert_array_equal(kept, inside)
    assert kept[: len(shape)].all() and kept[len(shape) :].any()
    # a segmenter's floor removal: nothing left within a centimetre of the floor
    removed = dataclasses.replace(every, floor_removed=1.0).crop(surrounded, shape, 0.5, rng)
    assert not (removed & (surrounded[:, 1] < shape[:, 1].min() + 0.01 / 0.5)).any()


def test_a_crop_view_is_a_named_rule_with_a_camera_above_the_floor() -> None:
    assert view_name_parts("occluded") == ("occluded", "", "")
    assert view_name_parts("paper+kinect_v2") == ("paper", "kinect_v2", "")
    assert view_name_parts("paper+kinect_v2+crop") == ("paper", "kinect_v2", "crop")
    assert view_name_parts("paper+kinect_v2+clutter") == ("paper", "kinect_v2", "clutter")
    with pytest.raises(ValueError, match="needs a camera"):
        view_name_parts("occluded+crop")
    with pytest.raises(ValueError, match="needs a camera"):
        view_name_parts("occluded+clutter")
    with pytest.raises(ValueError, match="unknown sensor"):
        view_name_parts("occluded+kinect_v9+crop")
    config = named_views("occluded+kinect_v2+crop", "night_stand")
    assert config.surroundings == Surroundings() and config.elevation == CROP_ELEVATION
    assert named_views("occluded+kinect_v2", "night_stand").surroundings is None
    # as a JSON config stores it
    assert scan_config({"surroundings": True}).surroundings == Surroundings()
    assert scan_config({"surroundings": False}).surroundings is None
    cluttered = named_views("paper+kinect_v2+clutter", "dresser").surroundings
    assert cluttered is not None and cluttered.on_top > 0.5
    assert dataclasses.replace(cluttered, on_top=0.0) == Surroundings()
    assert scan_config({"surroundings": {"on_top": 0.8, "on_top_count": [1, 2]}}).surroundings == (
        Surroundings(on_top=0.8, on_top_count=(1, 2))
    )


def test_things_stand_on_the_top_and_a_segmenters_crop_holds_them_whole() -> None:
    rng = np.random.default_rng(3)
    shape = _box_shape(rng)  # a top at y = 0.6, 0.6 m over the floor at 0.5 m a radius
    top = shape[:, 1].max()
    tops = top_points(shape, spacing=0.07, metre=2.0, rng=rng)
    assert len(tops) > 20 and (shape[tops, 1] > top - 0.021).all()  # the lid (1 cm), not the sides
    assert len(top_points(shape * [1.0, 0.1, 1.0], 0.07, 2.0, rng)) == 0  # a mat carries nothing
    laden = Surroundings(wall=0.0, neighbour=0.0, on_top=1.0, on_top_count=(3, 3), on_top_kept=1.0)
    surrounded, normals, boxed = laden.around(shape, spacing=0.07, radius_m=0.5, rng=rng)
    things = surrounded[len(shape) : boxed]
    assert len(things) > 30 and boxed < len(surrounded)  # the things, then the floor
    assert (things[:, 1] >= top - 1e-9).all() and things[:, 1].max() > top + 0.05 / 0.5
    assert (np.abs(things[:, [0, 2]]) < 0.5 + 0.3 / 0.5).all()  # on it, not beside it
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    # a segmenter's cluster holds them whole; a user's box around the piece holds their foot
    kept = laden.crop(surrounded, surrounded[:boxed], radius_m=0.5, rng=rng)
    assert kept[len(shape) : boxed].all()
    boxed_alone = dataclasses.replace(laden, grow_m=(0.05, 0.05))
    kept = boxed_alone.crop(surrounded, shape, radius_m=0.5, rng=rng)
    assert (surrounded[kept, 1] <= top + 0.05 / 0.5 + 1e-9).all() and kept[len(shape) : boxed].any()


def test_a_crop_view_holds_its_object_and_more_and_is_seeded() -> None:
    rng = np.random.default_rng(1)
    shape = _box_shape(rng)
    alone = named_views("occluded+kinect_v2", "night_stand")
    cropped = named_views("occluded+kinect_v2+crop", "night_stand")
    cropped = dataclasses.replace(
        cropped, surroundings=Surroundings(wall=1.0, neighbour=0.0, floor_removed=0.0)
    )
    below, beside = 0, 0
    for seed in range(6):
        scan, canonical_from_camera = scan_shape(shape, np.random.default_rng(seed), cropped)
        again, _ = scan_shape(shape, np.random.default_rng(seed), cropped)
        np.testing.assert_array_equal(scan, again)
        canonical = apply_rigid(canonical_from_camera, scan)
        below += int((canonical[:, 1] < shape[:, 1].min() + 0.02).sum())
        beside += int((np.abs(canonical[:, [0, 2]]) > [0.55, 0.45]).any(axis=1).sum())
        seen_alone, _ = scan_shape(shape, np.random.default_rng(seed), alone)
        assert np.isfinite(scan).all() and len(scan) >= cropped.min_points
        assert np.isfinite(seen_alone).all()
    assert below > 50  # the floor it stands on
    assert beside > 50  # the wall beside it
