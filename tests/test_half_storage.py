"""Model files with their weights stored as float16 and computed in float32."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper
from typer.testing import CliRunner

from itnet.cli import app
from itnet.export.half_storage import half_stored, store_half


def _graph(path: Path) -> Path:
    """A small float32 graph, x (B, 64) -> relu(x @ W + b) @ V, with a card-like metadata entry."""
    rng = np.random.default_rng(0)
    w = numpy_helper.from_array(rng.normal(size=(64, 128)).astype(np.float32), "w")
    v = numpy_helper.from_array(rng.normal(size=(128, 16)).astype(np.float32), "v")
    b = numpy_helper.from_array(rng.normal(size=(128,)).astype(np.float32), "b")
    nodes = [helper.make_node("MatMul", ["x", "w"], ["h"]), helper.make_node("Add", ["h", "b"], ["a"]),
             helper.make_node("Relu", ["a"], ["r"]), helper.make_node("MatMul", ["r", "v"], ["y"])]  # fmt: skip
    graph = helper.make_graph(
        nodes, "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["batch", 64])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["batch", 16])], [w, v, b],
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 20)])
    model.ir_version = 10
    entry = model.metadata_props.add()
    entry.key, entry.value = "itnet", '{"name": "g"}'
    onnx.save(model, str(path))
    return path


def _run(path: Path, x: np.ndarray) -> np.ndarray:
    return ort.InferenceSession(str(path)).run(None, {"x": x})[0]


def test_half_storage_computes_the_same_in_float32_from_half_the_bytes(tmp_path):
    path = _graph(tmp_path / "g.onnx")
    x = np.random.default_rng(1).normal(size=(8, 64)).astype(np.float32)
    before, size = _run(path, x), path.stat().st_size
    saved = store_half(path)
    assert saved > 0.45 * size and path.stat().st_size == size - saved
    after = _run(path, x)
    assert after.dtype == np.float32
    assert np.allclose(after, before, rtol=2e-3, atol=2e-3 * np.abs(before).max())
    model = onnx.load(str(path))
    kinds = {t.name: t.data_type for t in model.graph.initializer}
    assert kinds == {"w.float16": TensorProto.FLOAT16, "v.float16": TensorProto.FLOAT16,
                     "b": TensorProto.FLOAT}  # the bias (128 values) stays float32  # fmt: skip
    assert [(p.key, p.value) for p in model.metadata_props] == [("itnet", '{"name": "g"}')]
    assert store_half(path) == 0  # already compact: left as it is


def test_half_stored_leaves_the_model_it_was_given_alone(tmp_path):
    model = onnx.load(str(_graph(tmp_path / "g.onnx")))
    half = half_stored(model)
    assert {t.name for t in model.graph.initializer} == {"w", "v", "b"}
    assert len(half.graph.node) == len(model.graph.node) + 2  # a cast for each of w and v


def test_itnet_compact_rewrites_files_and_refuses_a_missing_one(tmp_path):
    path = _graph(tmp_path / "g.onnx")
    result = CliRunner().invoke(app, ["compact", str(path)])
    assert result.exit_code == 0, result.output
    assert "MB smaller" in result.stdout
    missing = CliRunner().invoke(app, ["compact", str(tmp_path / "none.onnx")])
    assert missing.exit_code == 2 and "no such file" in missing.output
