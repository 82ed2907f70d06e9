"""Robust fusion of several pose estimates (the ensemble mode's answer)."""

import numpy as np
import pytest

from itnet.fusion import fuse_poses, nearest_rotation
from itnet.geometry import (
    axis_angle_to_matrix,
    invert_rigid,
    random_rotation,
    rigid_from_rotation_translation,
    rotation_error_deg,
)
from itnet.symmetry import symmetry_group


def _pose(rotation, centre):
    """T_canonical_from_input putting the object's centre (input frame) at the origin."""
    r = np.asarray(rotation)
    return rigid_from_rotation_translation(r, -r @ np.asarray(centre))


def _noisy(rng, truth, centre, deg, shift):
    axis = rng.normal(size=3)
    turn = axis_angle_to_matrix(axis, np.radians(deg))
    return _pose(turn @ truth, np.asarray(centre) + rng.normal(scale=shift, size=3))


def test_one_pose_is_returned_unchanged(rng):
    t = _pose(random_rotation(rng), [1.0, 2.0, 3.0])
    assert np.allclose(fuse_poses(t[None]), t)


def test_nearest_rotation_is_a_rotation(rng):
    m = random_rotation(rng) + rng.normal(scale=0.2, size=(3, 3))
    r = nearest_rotation(m)
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(r), 1.0)


def test_outliers_are_ignored_and_inliers_averaged(rng):
    truth, centre = random_rotation(rng), np.array([0.5, -1.0, 2.0])
    good = [_noisy(rng, truth, centre, 4.0, 0.01) for _ in range(7)]
    bad = [_pose(random_rotation(rng), centre + 3.0) for _ in range(2)]  # other basins
    fused = fuse_poses(np.stack(good + bad))
    assert rotation_error_deg(fused[:3, :3], truth) < 3.0
    assert np.linalg.norm(invert_rigid(fused)[:3, 3] - centre) < 0.02
    # the plain mean of all nine would be pulled far off
    mean = nearest_rotation(np.stack(good + bad)[:, :3, :3].sum(0))
    assert rotation_error_deg(mean, truth) > rotation_error_deg(fused[:3, :3], truth)


def test_runs_half_a_turn_apart_fuse_under_yaw180(rng):
    truth, centre = random_rotation(rng), np.zeros(3)
    half = symmetry_group("yaw180")[1]
    runs = [_noisy(rng, truth, centre, 3.0, 0.0) for _ in range(3)]
    runs += [_noisy(rng, half @ truth, centre, 3.0, 0.0) for _ in range(3)]
    fused = fuse_poses(np.stack(runs), "yaw180")
    err = min(rotation_error_deg(fused[:3, :3], g @ truth) for g in symmetry_group("yaw180"))
    assert err < 3.0  # all six were used: one representative, not a blend of two
    blend = fuse_poses(np.stack(runs), "none")  # without the symmetry half are outliers
    assert (
        rotation_error_deg(blend[:3, :3], truth) < 5.0
        or rotation_error_deg(blend[:3, :3], half @ truth) < 5.0
    )


@pytest.mark.parametrize("symmetry", ["none", "yaw90", "yaw"])
def test_fused_pose_is_rigid(rng, symmetry):
    runs = np.stack([_pose(random_rotation(rng), rng.normal(size=3)) for _ in range(5)])
    fused = fuse_poses(runs, symmetry)
    r = fused[:3, :3]
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.allclose(fused[3], [0, 0, 0, 1])
