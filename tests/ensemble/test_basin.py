"""The ensemble's verifier: how firmly each run sits in its basin (itnet.basin), and the fusion
anchored by the firmest run (fusion.fuse_poses(anchor=...))."""

import numpy as np

from itnet.basin import UNSURE_DEG, basin_drift, firm_anchor, probe_turns
from itnet.fusion import fuse_poses, medoid_index, nearest_rotation
from itnet.geometry import (
    axis_angle_to_matrix,
    random_rotation,
    rotation_angle_deg,
    rotation_error_deg,
)


def _attracted_to_identity(x: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """A toy network step: a pose within 60° of the identity moves halfway to it (the polar
    factor of I + R is R's square root), a pose farther off stays where it is."""
    out = poses.copy()
    for b, pose in enumerate(poses):
        r = pose[:3, :3].astype(np.float64)
        if rotation_angle_deg(r) < 60:
            out[b, :3, :3] = nearest_rotation(np.eye(3) + r)
    return out


def test_probe_turns_are_turns_of_the_angle_about_different_axes():
    turns = probe_turns(30.0)
    assert turns.shape == (4, 4, 4) and np.allclose(turns[:, :3, 3], 0)
    assert np.allclose(rotation_angle_deg(turns[:, :3, :3]), 30.0)
    assert rotation_error_deg(turns[0, :3, :3], turns[1, :3, :3]) > 30.0


def test_a_run_in_the_networks_basin_drifts_less_than_one_where_it_is_not_held(rng):
    """A pose at the attractor comes back after the probes (drift ~30/2^5 degrees); a pose the
    network leaves where it is keeps the probes' whole turn (30°)."""
    far = np.eye(4)
    far[:3, :3] = axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), np.radians(90.0))
    poses = np.stack([np.eye(4), far, np.eye(4)]).astype(np.float32)
    points = rng.normal(size=(3, 16, 3)).astype(np.float32)
    drift = basin_drift(_attracted_to_identity, points, poses, probe_turns(30.0), steps=5)
    assert drift.shape == (3,)
    assert drift[0] < 2.0 and drift[2] < 2.0 and abs(drift[1] - 30.0) < 1e-3
    assert int(np.argmin(drift)) in (0, 2)


def test_the_anchored_fusion_follows_its_anchor_not_the_majority(rng):
    """Five runs in one basin, three in another: the plain fusion takes the five; anchored by
    one of the three, it takes the three (and their mean, not the anchor alone)."""
    a, b = random_rotation(rng), random_rotation(rng)
    while rotation_error_deg(a, b) < 90:
        b = random_rotation(rng)
    poses = np.tile(np.eye(4), (8, 1, 1))
    for k in range(8):
        turn = axis_angle_to_matrix(rng.normal(size=3), np.radians(3.0))
        poses[k, :3, :3] = turn @ (a if k < 5 else b)
    assert rotation_error_deg(fuse_poses(poses)[:3, :3], a) < 3.0
    anchored = fuse_poses(poses, anchor=6)
    assert rotation_error_deg(anchored[:3, :3], b) < 3.0
    assert not np.allclose(anchored[:3, :3], poses[6, :3, :3])  # the three's mean
    assert np.allclose(fuse_poses(poses, anchor=None), fuse_poses(poses))


def test_the_medoid_keeps_its_place_while_it_holds_its_pose():
    drift = np.array([4.0, 2.0, 25.0, 1.0])
    assert firm_anchor(drift, medoid=0) == 0  # holds (4° <= UNSURE_DEG): the majority stays
    assert firm_anchor(drift, medoid=2) == 3  # does not: the firmest run takes its place
    assert firm_anchor(np.array([UNSURE_DEG, 0.0]), medoid=0) == 0


def test_the_medoid_is_the_one_the_plain_fusion_centres_on(rng):
    a = random_rotation(rng)
    poses = np.tile(np.eye(4), (5, 1, 1))
    for k in range(5):
        deg = 2.0 if k < 3 else 150.0
        poses[k, :3, :3] = axis_angle_to_matrix(rng.normal(size=3), np.radians(deg)) @ a
    medoid = medoid_index(poses)
    assert medoid < 3
    assert np.allclose(fuse_poses(poses, anchor=medoid), fuse_poses(poses))
