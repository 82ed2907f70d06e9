"""shape_misses: the error rotation left after the nearest symmetry turn, its kind, and the
shapes a model misses in most of their views."""

from __future__ import annotations

import numpy as np

from benchmarks.shape_misses import by_shape, error_turns, turn_kind
from itnet.geometry import axis_angle_to_matrix, random_rotation


def test_error_turn_is_the_rotation_between_estimate_and_truth() -> None:
    rng = np.random.default_rng(0)
    truth = random_rotation(rng, 3)
    turns = axis_angle_to_matrix(
        np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.radians([180, 90, 30])
    )
    angles, axes = error_turns(turns @ truth, truth)
    np.testing.assert_allclose(angles, [180, 90, 30], atol=1e-6)
    np.testing.assert_allclose(axes, np.eye(3)[[1, 0, 2]], atol=1e-6)


def test_a_symmetric_category_counts_the_error_from_the_nearest_equivalent_pose() -> None:
    truth = random_rotation(np.random.default_rng(1), 2)
    half_yaw = axis_angle_to_matrix([0.0, 1.0, 0.0], np.pi)
    tilt = axis_angle_to_matrix([1.0, 0.0, 0.0], np.radians(25))
    estimate = np.stack([half_yaw @ truth[0], tilt @ half_yaw @ truth[1]])
    asymmetric, _ = error_turns(estimate, truth, "none")
    symmetric, axes = error_turns(estimate, truth, "yaw180")
    np.testing.assert_allclose(asymmetric[0], 180, atol=1e-6)
    np.testing.assert_allclose(symmetric, [0, 25], atol=1e-5)
    np.testing.assert_allclose(axes[1], [1, 0, 0], atol=1e-6)


def test_turn_kinds() -> None:
    y, x = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    mixed = np.array([0.6, 0.6, 0.53])
    assert turn_kind(5.0, y) == "centre only"
    assert turn_kind(15.0, y) == "near miss"
    assert turn_kind(178.0, y) == "half turn about y"
    assert turn_kind(91.0, x) == "quarter turn about x"
    assert turn_kind(178.0, mixed) == "other"
    assert turn_kind(40.0, y) == "other"


def test_shapes_missed_in_most_views_are_listed_with_their_commonest_turn() -> None:
    names = ["a"] * 4 + ["b"] * 4 + ["c"] * 4
    wrong = [True, True, True, False, True, False, False, False, True, True, True, True]
    y, x = [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]
    angles = [179, 178, 90, 2, 170, 1, 1, 1, 95, 92, 5, 179]
    axes = [y, y, x, y, y, y, y, y, x, x, y, y]
    split, shapes = by_shape(names, wrong, angles, axes, min_share=0.75)
    assert split == {
        "half turn about y": 4,
        "quarter turn about x": 3,
        "centre only": 1,
    }
    assert [s["shape"] for s in shapes] == ["c", "a"]  # b: 1 of 4 missed
    assert shapes[0] == {
        "shape": "c",
        "views": 4,
        "missed": 4,
        "median_error_deg": 93.5,
        "turn": "quarter turn about x",
        "turn_views": 2,
    }
    assert shapes[1]["turn"] == "half turn about y" and shapes[1]["turn_views"] == 2
