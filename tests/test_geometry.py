import numpy as np
import pytest

from itnet import geometry as g


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_quaternion_matrix_round_trip(rng, dtype):
    q = rng.normal(size=(500, 4)).astype(dtype)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    r = g.quat_wxyz_to_matrix(q)
    assert np.allclose(g.matrix_to_quat_wxyz(r), q, atol=1e-5)
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-6)
    assert np.allclose(np.linalg.det(r), 1.0, atol=1e-6)


def test_matrix_to_quat_handles_half_turns():
    # 180° rotations make w = 0: the branch on the largest component must still be right.
    for axis in np.eye(3):
        r = g.axis_angle_to_matrix(axis, np.pi)
        assert np.allclose(g.quat_wxyz_to_matrix(g.matrix_to_quat_wxyz(r)), r, atol=1e-12)


def test_wxyz_xyzw_round_trip_and_order():
    q = np.array([0.9, 0.1, 0.2, 0.3])
    assert np.allclose(g.quat_wxyz_to_xyzw(q), [0.1, 0.2, 0.3, 0.9])
    assert np.allclose(g.quat_xyzw_to_wxyz(g.quat_wxyz_to_xyzw(q)), q)


def test_batch_shapes_are_kept(rng):
    r = g.random_rotation(rng, 6).reshape(2, 3, 3, 3)
    assert g.matrix_to_quat_wxyz(r).shape == (2, 3, 4)
    assert g.rotation_angle_deg(r).shape == (2, 3)


def test_invert_and_apply(rng):
    pose = g.rigid_from_rotation_translation(g.random_rotation(rng), rng.normal(size=3))
    pts = rng.normal(size=(50, 3))
    assert np.allclose(g.apply_rigid(g.invert_rigid(pose), g.apply_rigid(pose, pts)), pts)
    assert np.allclose(g.invert_rigid(pose) @ pose, np.eye(4))


def test_rotation_angle_matches_axis_angle(rng):
    angles = rng.uniform(0, np.pi, size=100)
    r = g.axis_angle_to_matrix(rng.normal(size=(100, 3)), angles)
    assert np.allclose(g.rotation_angle_deg(r), np.degrees(angles), atol=1e-6)
    # The clamp keeps the identity (trace slightly above 3 in float) at exactly 0, not NaN.
    assert g.rotation_angle_deg(np.eye(3) * (1 + 1e-12)) == 0.0


def test_rotation_error_is_symmetric_and_invariant(rng):
    a, b, c = g.random_rotation(rng, 3)
    assert np.isclose(g.rotation_error_deg(a, b), g.rotation_error_deg(b, a))
    assert np.isclose(g.rotation_error_deg(c @ a, c @ b), g.rotation_error_deg(a, b))


def test_random_rotations_are_uniform(rng):
    # For uniform SO(3), the mean of R is the zero matrix and E[angle] = pi/2 + 2/pi rad.
    r = g.random_rotation(rng, 20000)
    assert np.abs(r.mean(0)).max() < 0.02
    assert abs(np.radians(g.rotation_angle_deg(r)).mean() - (np.pi / 2 + 2 / np.pi)) < 0.02


@pytest.mark.parametrize("count", [1, 3, 4, 6])
def test_viewing_axis_turns_are_evenly_spread_about_z(count):
    turns = g.viewing_axis_turns(count)
    assert turns.shape == (count, 3, 3) and np.allclose(turns[0], np.eye(3))
    assert np.allclose(turns @ np.swapaxes(turns, -1, -2), np.eye(3), atol=1e-12)
    assert np.allclose(turns[:, :, 2], [0.0, 0.0, 1.0])  # z stays put
    if count > 2:  # neighbours 360/count apart (with 1 or 2 the angle folds past 180)
        steps = g.rotation_error_deg(turns, np.roll(turns, -1, axis=0))
        assert np.allclose(steps, 360.0 / count)
