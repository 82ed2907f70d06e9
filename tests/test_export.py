import numpy as np
import pytest
import torch

from itnet.model_card import ModelCard
from itnet.pose.runtime import load_model


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


def test_folded_step_is_the_network_step(tiny_net, rng):
    """The export graph (BatchNorm folded, channels-first, pool before bias+ReLU) computes the
    same function as the training network in eval mode."""
    from itnet.model.network import ExportableStep

    x = torch.from_numpy(rng.normal(size=(3, 50, 3)).astype(np.float32))
    pose = torch.eye(4).expand(3, 4, 4).contiguous()
    with torch.no_grad():
        want, _ = tiny_net.step(x, pose)
        got, _ = ExportableStep(tiny_net)(x, pose)
    assert torch.abs(got - want).max() < 1e-5


def test_int8_graph_is_close_to_float_and_marked(tiny_model_dir, tmp_path, rng):
    import onnx

    from itnet.export.quantize import quantize_point_layers
    from itnet.geometry import rotation_error_deg

    path = quantize_point_layers(
        tiny_model_dir / "tiny.onnx", tmp_path / "tiny8.onnx", name="tiny8"
    )
    ops = {n.op_type for n in onnx.load(str(path)).graph.node}
    assert ops & {"MatMulInteger", "DynamicQuantizeMatMul", "MatMulIntegerToFloat"}
    fp32, int8 = (load_model(p, warm_up=False) for p in (tiny_model_dir / "tiny.onnx", path))
    assert int8.card.precision == "int8" and int8.card.name == "tiny8"
    assert fp32.card.precision == "float32"
    x = rng.normal(size=(4, 256, 3)).astype(np.float32)
    pose = np.tile(np.eye(4, dtype=np.float32), (4, 1, 1))
    want, got = fp32.step(x, pose)[0], int8.step(x, pose)[0]
    assert np.abs(want - np.eye(4)).max() > 1e-3  # the update is not trivially the identity
    angle = rotation_error_deg(got[:, :3, :3], want[:, :3, :3])
    assert angle.max() < 1.0 and np.abs(got[:, :3, 3] - want[:, :3, 3]).max() < 0.02


def test_quantize_refuses_a_graph_without_the_point_layers(tmp_path):
    import onnx
    from onnx import TensorProto, helper

    from itnet.export.quantize import quantize_point_layers

    graph = helper.make_graph(
        [helper.make_node("Relu", ["x"], ["y"])],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])],
    )
    onnx.save(helper.make_model(graph), str(tmp_path / "relu.onnx"))
    with pytest.raises(ValueError, match="point_w"):
        quantize_point_layers(tmp_path / "relu.onnx", tmp_path / "out.onnx")


def test_6d_rotation_step_exports_and_matches_torch(make_net, tmp_path, rng):
    """A network with the 6D rotation (Gram-Schmidt in the graph): the folded step and the ONNX
    graph, int8 too, compute its pose; every update is a rotation; the served loop runs it."""
    from itnet.export.onnx_export import export_step
    from itnet.export.quantize import quantize_point_layers
    from itnet.model.network import ExportableStep

    net = make_net(seed=3, rotation="6d")
    card = ModelCard(name="six", category="chair", points=256, recommended_iterations=5)
    export_step(net, card, tmp_path / "six.onnx")
    quantize_point_layers(tmp_path / "six.onnx", tmp_path / "six-int8.onnx")
    x = rng.normal(size=(4, 300, 3)).astype(np.float32)
    pose = np.eye(4, dtype=np.float32)[None].repeat(4, 0)
    pose[:, :3, 3] = rng.normal(size=(4, 3))
    with torch.no_grad():
        want, want_delta = net.step(torch.from_numpy(x), torch.from_numpy(pose))
        folded, _ = ExportableStep(net)(torch.from_numpy(x), torch.from_numpy(pose))
    assert torch.abs(folded - want).max() < 1e-5
    got, delta = load_model(tmp_path / "six.onnx", warm_up=False).step(x, pose)
    assert np.abs(got - want.numpy()).max() < 1e-4
    rotation = delta[:, :3, :3]
    assert np.allclose(rotation @ rotation.transpose(0, 2, 1), np.eye(3), atol=1e-5)
    assert np.allclose(np.linalg.det(rotation), 1.0, atol=1e-5)
    assert np.abs(want_delta.numpy() - np.eye(4)).max() > 1e-3  # not trivially the identity
    quantized, _ = load_model(tmp_path / "six-int8.onnx", warm_up=False).step(x, pose)
    assert np.abs(quantized - want.numpy()).max() < 0.05
