"""Finishing a pose by the object's mirror symmetry (itnet.mirror)."""

import numpy as np
import pytest

from itnet.geometry import apply_rigid, axis_angle_to_matrix, invert_rigid, rotation_error_deg
from itnet.mirror import mirror_refined


def symmetric_cloud(rng: np.random.Generator) -> np.ndarray:
    """A surface-like cloud (2N, 3), mirror-symmetric about x = 0 and about no other plane, with
    an RMS radius of 1: the faces of a box, a post up and forward on it."""
    p = rng.uniform(-1, 1, size=(3000, 3))
    face = rng.integers(3, size=len(p))
    p[np.arange(len(p)), face] = rng.choice([-1.0, 1.0], size=len(p))
    box = p * [1.0, 0.5, 0.7]
    post = rng.uniform(-1, 1, size=(600, 3)) * [0.08, 0.6, 0.08] + [0.6, 1.1, -0.4]
    half = np.concatenate([box[box[:, 0] >= 0], post])
    cloud = np.concatenate([half, half * [-1.0, 1.0, 1.0]])
    cloud -= cloud.mean(0)
    return cloud / np.sqrt((cloud**2).sum(1).mean())


def off_pose(turn_deg_y: float, turn_deg_z: float, shift_x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = axis_angle_to_matrix([0, 1, 0], np.radians(turn_deg_y)) @ axis_angle_to_matrix(
        [0, 0, 1], np.radians(turn_deg_z)
    )
    pose[0, 3] = shift_x
    return pose


def test_a_pose_off_in_yaw_roll_and_x_is_brought_back():
    """The cloud is seen through a wrong pose; refining it finds the plane again."""
    canonical = symmetric_cloud(np.random.default_rng(0))
    error = off_pose(6.0, -4.0, 0.05)
    cloud = apply_rigid(invert_rigid(error), canonical)  # what the estimate would move wrongly
    pose = np.eye(4)  # the estimate: identity, so it is off by ``error``
    refined = mirror_refined(cloud, pose)
    moved = apply_rigid(refined, cloud)
    assert rotation_error_deg(refined[:3, :3], error[:3, :3]) < 2.5
    assert np.abs(moved - canonical).max() < 0.1
    before = rotation_error_deg(pose[:3, :3], error[:3, :3])
    assert before > 7.0  # it was off, and is not now


def test_a_symmetric_pose_is_left_alone_and_a_large_turn_refused():
    canonical = symmetric_cloud(np.random.default_rng(1))
    assert np.allclose(mirror_refined(canonical, np.eye(4)), np.eye(4), atol=1e-6)
    cloud = apply_rigid(invert_rigid(off_pose(8.0, 0.0, 0.0)), canonical)
    assert np.array_equal(mirror_refined(cloud, np.eye(4), max_turn_deg=2.0), np.eye(4))


def test_a_plane_far_from_the_estimates_is_refused():
    line = np.zeros((50, 3))
    line[:, 0] = np.linspace(0.5, 2.0, 50)  # symmetric about x = 1.25, not near x = 0
    pose = np.eye(4)
    assert np.array_equal(mirror_refined(line, pose), pose)
    with pytest.raises(ValueError):
        mirror_refined(np.zeros((0, 3)), pose)


def test_stopping_once_settled_gives_the_pose_of_all_rounds():
    canonical = symmetric_cloud(np.random.default_rng(2))
    cloud = apply_rigid(invert_rigid(off_pose(5.0, 3.0, -0.04)), canonical)
    settled = mirror_refined(cloud, np.eye(4))
    every_round = mirror_refined(cloud, np.eye(4), settled=0.0)
    assert rotation_error_deg(settled[:3, :3], every_round[:3, :3]) < 0.05
    assert np.abs(settled[:3, 3] - every_round[:3, 3]).max() < 1e-3
    assert not np.allclose(settled, np.eye(4))  # and both did move it


def test_two_planes_also_fix_the_turn_about_x():
    """A box-like shape symmetric left-right and front-back, seen through a pose turned about x
    (which the x = 0 plane cannot see) and about y: 'x' then 'z' undo both."""
    from itnet.mirror import mirror_finished

    rng = np.random.default_rng(4)
    p = rng.uniform(-1, 1, size=(4000, 3))
    face = rng.integers(3, size=len(p))
    p[np.arange(len(p)), face] = rng.choice([-1.0, 1.0], size=len(p))
    box = p * [1.0, 0.5, 0.7]
    top = box[:, 1] > 0.45  # a lid wider than the box: no plane of symmetry but x = 0, z = 0, y
    box[top] *= [1.15, 1.0, 1.15]
    canonical = (box - box.mean(0)) / np.sqrt(((box - box.mean(0)) ** 2).sum(1).mean())
    error = np.eye(4)
    error[:3, :3] = axis_angle_to_matrix([1, 0, 0], np.radians(6.0)) @ axis_angle_to_matrix(
        [0, 1, 0], np.radians(4.0)
    )
    cloud = apply_rigid(invert_rigid(error), canonical)
    # a box's flat faces make point-to-point ICP slow: more rounds than real scans need (20)
    only_x = mirror_finished(cloud, np.eye(4), ["x"], iterations=200)
    both = mirror_finished(cloud, np.eye(4), ["x", "z"], iterations=200)
    assert rotation_error_deg(both[:3, :3], error[:3, :3]) < 1.5
    assert rotation_error_deg(only_x[:3, :3], error[:3, :3]) > 4.0  # the turn about x is left
    assert np.array_equal(mirror_finished(cloud, np.eye(4), []), np.eye(4))
    with pytest.raises(ValueError, match="unknown mirror plane"):
        mirror_finished(cloud, np.eye(4), ["y"])


def test_rotation_error_cdfs_are_plotted(tmp_path):
    from itnet.model.plots import plot_rotation_cdfs

    rng = np.random.default_rng(5)
    errors = {"one run": rng.gamma(2.0, 2.5, 300), "+ mirror": rng.gamma(2.0, 1.5, 300)}
    path = plot_rotation_cdfs(errors, tmp_path / "cdf.png", "two options")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000
