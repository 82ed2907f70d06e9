"""float32 weights stored as float16 in an ONNX file, computed in float32.

A shipped graph's large float32 initializers (the pose step's head MLP, the classifiers, the
verifiers) are written as float16 with a ``Cast`` back to float32 in front of their users:
half the bytes on disk and in the wheel, the same float32 arithmetic at run time
(onnxruntime folds the casts when it loads the graph). Each weight moves by at most half a
float16 step (a relative 2**-11); graphs and cards are otherwise unchanged.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

SMALLEST = 1024  # initializers with fewer values (biases, shapes) stay as they are


def half_stored(model: onnx.ModelProto, smallest: int = SMALLEST) -> onnx.ModelProto:
    """``model`` with every float32 initializer of at least ``smallest`` values stored as float16
    and cast back to float32 where it is read. Returns a new model; metadata (the card) kept."""
    out = onnx.ModelProto()
    out.CopyFrom(model)
    graph = out.graph
    kept, casts = [], []
    for tensor in graph.initializer:
        values = int(np.prod(tensor.dims)) if tensor.dims else 1
        if tensor.data_type != TensorProto.FLOAT or values < smallest:
            kept.append(tensor)
            continue
        half = numpy_helper.from_array(
            numpy_helper.to_array(tensor).astype(np.float16), f"{tensor.name}.float16"
        )
        kept.append(half)
        cast = helper.make_node(
            "Cast", [half.name], [tensor.name], to=TensorProto.FLOAT, name=f"{tensor.name}.cast"
        )
        casts.append(cast)
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = list(graph.node)
    del graph.node[:]
    graph.node.extend(casts + nodes)
    onnx.checker.check_model(out)
    return out


def store_half(path: Path, smallest: int = SMALLEST) -> int:
    """Rewrite the ONNX file at ``path`` with its large weights stored as float16; returns the
    bytes saved. A file already stored so is left as it is (0)."""
    model = onnx.load(str(path))
    if any(t.name.endswith(".float16") for t in model.graph.initializer):
        return 0
    before = path.stat().st_size
    onnx.save(half_stored(model, smallest), str(path))
    return before - path.stat().st_size
