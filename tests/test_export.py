import numpy as np
import pytest
import torch

from itnet.model_card import ModelCard
from itnet.service.runtime import load_model


@pytest.mark.parametrize(("batch", "points"), [(1, 1024), (3, 100), (8, 37), (2, 4096)])
def test_onnx_matches_torch_on_random_weights(tiny_model_dir, tiny_net, batch, points, rng):
    net = tiny_net
    model = load_model(tiny_model_dir / "tiny.onnx", warm_up=False)
    x = rng.normal(size=(batch, points, 3)).astype(np.float32)
    # a non-identity starting pose exercises the transform-then-compose path of the graph
    q = rng.normal(size=(batch, 4))
    from itnet.geometry import quat_wxyz_to_matrix, rigid_from_rotation_translation

    pose = rigid_from_rotation_translation(quat_wxyz_to_matrix(q), rng.normal(size=(batch, 3)))
    pose = pose.astype(np.float32)
    got_next, got_delta = model.step(x, pose)
    with torch.no_grad():
        want_next, want_delta = net.step(torch.from_numpy(x), torch.from_numpy(pose))
    assert np.abs(got_next - want_next.numpy()).max() < 1e-4  # stated tolerance (float32)
    assert np.abs(got_delta - want_delta.numpy()).max() < 1e-4
    assert np.abs(want_delta.numpy() - np.eye(4)).max() > 1e-3  # not trivially the identity


def test_model_card_travels_in_the_file(tiny_model_dir):
    model = load_model(tiny_model_dir / "tiny.onnx", warm_up=False)
    assert model.card == ModelCard(
        name="tiny", category="chair", points=256, recommended_iterations=5
    )
    assert (tiny_model_dir / "tiny.onnx").stat().st_size < 1_000_000  # a single small file
    assert list(tiny_model_dir.iterdir()) == [tiny_model_dir / "tiny.onnx"]  # no external data
