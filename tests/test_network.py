import numpy as np
import pytest
import torch

from itnet.geometry import quat_wxyz_to_matrix
from itnet.model.network import ITNet, NetworkConfig, point_loss, quat_wxyz_translation_to_pose


def test_quaternion_to_pose_matches_numpy(rng):
    out = rng.normal(size=(20, 7))
    pose = quat_wxyz_translation_to_pose(torch.tensor(out)).numpy()
    assert np.allclose(pose[:, :3, :3], quat_wxyz_to_matrix(out[:, :4]), atol=1e-12)
    assert np.allclose(pose[:, :3, 3], out[:, 4:])
    assert np.allclose(pose[:, 3], [0, 0, 0, 1])


def test_identity_init_returns_the_identity_at_every_iteration():
    net = ITNet().eval()
    poses = net(torch.randn(3, 100, 3), iterations=4)
    for pose in poses:
        assert torch.allclose(pose, torch.eye(4).expand(3, 4, 4), atol=1e-6)


def test_without_identity_init_the_first_step_is_not_the_identity():
    torch.manual_seed(0)
    net = ITNet(NetworkConfig(identity_init=False)).eval()
    pose = net(torch.randn(2, 64, 3), iterations=1)[0]
    assert (pose - torch.eye(4)).abs().max() > 1e-3


def _trainable_net(seed: int = 0) -> ITNet:
    torch.manual_seed(seed)
    net = ITNet(
        NetworkConfig(point_channels=(8, 16, 32), head_channels=(16, 8), identity_init=False)
    )
    return net.train()


@pytest.mark.parametrize("stop", [True, False])
def test_stop_gradient_cuts_only_the_path_through_the_moved_input(stop):
    """With stop-grad, d(loss)/d(pose_1) reaches pose_1 only through the composition
    pose_2 = dT_2 @ pose_1, not through the regressor's input at iteration 2."""
    net = _trainable_net()
    x = torch.randn(4, 32, 3)
    pose1 = net(x, 1)[0].detach().requires_grad_(True)
    pose2, delta2 = net.step(x, pose1, stop_gradient=stop)
    target = torch.eye(4).expand(4, 4, 4)
    grad_full = torch.autograd.grad(point_loss(pose2, target, x), pose1)[0]
    # The gradient through the composition alone: treat dT_2 as a constant.
    composed = delta2.detach() @ pose1
    grad_compose = torch.autograd.grad(point_loss(composed, target, x), pose1)[0]
    same = torch.allclose(grad_full, grad_compose, atol=1e-6)
    assert same == stop


def test_training_reduces_the_loss_on_a_small_set():
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    base = torch.tensor(rng.normal(size=(64, 3)) * [1.0, 0.5, 0.2], dtype=torch.float32)
    angles = torch.tensor(rng.uniform(-0.6, 0.6, size=8), dtype=torch.float32)
    c, s = torch.cos(angles), torch.sin(angles)
    rot = torch.zeros(8, 3, 3)
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1
    x = base @ rot.transpose(1, 2)  # input = rotated shape; target pose = inverse rotation
    target = torch.eye(4).repeat(8, 1, 1)
    target[:, :3, :3] = rot.transpose(1, 2)
    net = ITNet(NetworkConfig(point_channels=(16, 32, 64), head_channels=(32, 16)))
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    losses = []
    for _ in range(60):
        loss = point_loss(net(x, 2)[-1], target, x)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss))
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])


def test_exported_update_is_the_quaternion_pose_for_any_quaternion_length():
    from itnet.model.network import ExportableStep

    step = ExportableStep(ITNet(NetworkConfig()).eval())
    gen = torch.Generator().manual_seed(5)
    output = torch.randn(256, 7, generator=gen) * torch.tensor([4.0, 4, 4, 4, 1, 1, 1])
    got, want = step.update(output), quat_wxyz_translation_to_pose(output)
    assert torch.allclose(got, want, atol=2e-6)
    rotation = got[:, :3, :3]
    eye = torch.eye(3).expand(256, 3, 3)
    assert torch.allclose(rotation @ rotation.transpose(1, 2), eye, atol=2e-6)  # a rotation


def test_distance_loss_is_the_mean_point_distance_and_keeps_its_gradient_near_the_target():
    """``kind="distance"`` is mean ||T x - T* x|| (the paper's is its square); near the target
    its gradient keeps its size where the squared loss's fades."""
    x = torch.randn(2, 50, 3, dtype=torch.float64)
    target = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    for offset in (0.5, 0.01):
        shift = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
        shift[:, 0, 3] = offset
        assert torch.isclose(
            point_loss(shift, target, x, kind="distance"), torch.tensor(offset, dtype=torch.float64)
        )
        assert torch.isclose(
            point_loss(shift, target, x), torch.tensor(offset**2, dtype=torch.float64)
        )
    grads = {}
    for kind in ("squared", "distance"):
        pose = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
        pose[:, 0, 3] = 0.01
        pose.requires_grad_(True)
        point_loss(pose, target, x, kind=kind).backward()
        grads[kind] = pose.grad[:, 0, 3].abs().sum().item()
    assert grads["distance"] > 20 * grads["squared"]
    exact = torch.eye(4).expand(2, 4, 4).clone().requires_grad_(True)
    point_loss(exact, torch.eye(4).expand(2, 4, 4), x.float(), kind="distance").backward()
    assert torch.isfinite(exact.grad).all()  # finite at zero distance
    with pytest.raises(ValueError, match="unknown point loss"):
        point_loss(exact, target.float(), x.float(), kind="cubic")


def test_6d_rotation_reads_two_columns_and_starts_at_the_identity(rng):
    """six_d_translation_to_pose: a rotation's own first two columns (scaled, the second
    skewed toward the first) give it back; any output gives a rotation; the identity init too."""
    from itnet.model.network import six_d_translation_to_pose

    rotation = quat_wxyz_to_matrix(rng.normal(size=(5, 4)))
    scale = rng.uniform(0.5, 3.0, size=(5, 1))
    a1 = rotation[:, :, 0] * scale
    a2 = rotation[:, :, 1] * 2.0 + 0.7 * rotation[:, :, 0]  # not orthogonal to a1
    t = rng.normal(size=(5, 3))
    pose = six_d_translation_to_pose(torch.from_numpy(np.concatenate([a1, a2, t], axis=1)))
    assert np.allclose(pose[:, :3, :3].numpy(), rotation, atol=1e-10)
    assert np.allclose(pose[:, :3, 3].numpy(), t) and np.allclose(pose[:, 3].numpy(), [0, 0, 0, 1])
    any_output = six_d_translation_to_pose(torch.randn(64, 9, dtype=torch.float64))[:, :3, :3]
    assert torch.allclose(
        any_output @ any_output.transpose(1, 2), torch.eye(3, dtype=torch.float64)
    )
    assert torch.allclose(torch.linalg.det(any_output), torch.ones(64, dtype=torch.float64))
    net = ITNet(NetworkConfig(rotation="6d")).eval()
    for pose in net(torch.randn(2, 100, 3), 3):
        assert torch.allclose(pose, torch.eye(4).expand(2, 4, 4), atol=1e-6)
    with pytest.raises(ValueError, match="unknown rotation"):
        NetworkConfig(rotation="euler")
