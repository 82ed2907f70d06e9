"""Symmetry groups about up, symmetry-aware errors and the symmetry-aware PLoss."""

import numpy as np
import pytest

from itnet.geometry import axis_angle_to_matrix, random_rotation
from itnet.symmetry import SYMMETRY_NAMES, symmetric_rotation_error_deg, symmetry_group


@pytest.mark.parametrize(("name", "size"), [("none", 1), ("yaw180", 2), ("yaw90", 4), ("yaw", 360)])
def test_groups_are_turns_about_up_identity_first(name, size):
    group = symmetry_group(name)
    assert group.shape == (size, 3, 3)
    assert np.allclose(group[0], np.eye(3))
    assert np.allclose(group @ [0.0, 1.0, 0.0], [0.0, 1.0, 0.0])  # up stays up
    assert np.allclose(group @ group.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(group), 1.0)


def test_groups_are_built_once_and_cannot_be_changed_by_a_caller():
    group = symmetry_group("yaw90", 8)
    assert symmetry_group("yaw90", 8) is group  # shared: the ensemble fuses after every step
    with pytest.raises(ValueError, match="read-only"):
        group[0, 0, 0] = 2.0
    assert symmetry_group("yaw90", 9) is not group and len(symmetry_group("yaw", 9)) == 9


def test_unknown_symmetry_is_refused():
    with pytest.raises(ValueError, match="unknown symmetry"):
        symmetry_group("mirror")


@pytest.mark.parametrize("name", SYMMETRY_NAMES)
def test_every_equivalent_pose_has_zero_error(name, rng):
    truth = random_rotation(rng)
    for turn in symmetry_group(name, yaw_samples=12):
        assert symmetric_rotation_error_deg(turn @ truth, truth, name) < 1e-5


def test_a_turn_outside_the_group_still_counts(rng):
    truth = random_rotation(rng, size=5)
    quarter = axis_angle_to_matrix([0.0, 1.0, 0.0], np.pi / 2)
    assert np.allclose(symmetric_rotation_error_deg(quarter @ truth, truth, "yaw180"), 90.0)
    assert np.allclose(symmetric_rotation_error_deg(quarter @ truth, truth, "none"), 90.0)
    # any turn about up is free for round objects (to the group's 1 degree sampling)
    odd = axis_angle_to_matrix([0.0, 1.0, 0.0], np.radians(37.3))
    assert np.all(symmetric_rotation_error_deg(odd @ truth, truth, "yaw") < 0.51)
    # a tilt is never free: 20 degrees about x stays 20 degrees under every group
    tilt = axis_angle_to_matrix([1.0, 0.0, 0.0], np.radians(20.0))
    for name in SYMMETRY_NAMES:
        assert np.allclose(symmetric_rotation_error_deg(tilt @ truth, truth, name), 20.0, atol=0.6)


def test_symmetric_point_loss_takes_the_best_equivalent_target(rng):
    torch = pytest.importorskip("torch")
    from itnet.model.network import point_loss

    points = torch.from_numpy(rng.normal(size=(3, 50, 3)).astype(np.float32))
    target = torch.eye(4).repeat(3, 1, 1)
    target[:, :3, 3] = torch.tensor([0.1, -0.2, 0.3])
    half = torch.eye(4)
    half[:3, :3] = torch.from_numpy(symmetry_group("yaw180")[1].astype(np.float32))
    turns = torch.stack([torch.eye(4), half]).repeat(3, 1, 1, 1)  # (3, 2, 4, 4)
    estimate = (half @ target).clone().requires_grad_(True)  # a half turn off
    assert float(point_loss(estimate, target, points)) > 0.5  # plain PLoss: wrong
    loss = point_loss(estimate, target, points, turns)
    assert float(loss) < 1e-10  # symmetric PLoss: right
    # with only the identity as the group it equals the plain loss
    alone = turns[:, :1]
    assert torch.allclose(
        point_loss(estimate, target, points, alone), point_loss(estimate, target, points)
    )
    loss.backward()
    assert torch.isfinite(estimate.grad).all()


def test_alignment_hypotheses_cover_the_declared_symmetry():
    from itnet.alignment.hypotheses import rival_turns, symmetry_rotations

    assert rival_turns("chair") == "yaw90"  # the chair's usual confusions
    assert rival_turns("mug") == "yaw180"  # unknown category, no declared symmetry
    assert rival_turns("mug", "yaw") == "yaw"  # round: every 30 degrees
    assert rival_turns("table", "yaw180") == "yaw90"  # the table's confusions include it
    turns = symmetry_rotations("yaw")
    assert len(turns) == 11 and np.allclose(turns @ [0.0, 1.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0])
