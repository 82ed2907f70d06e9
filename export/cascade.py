"""A fused classifier graph made a cascade: the other heads run only where the first is unsure.

A fused graph (``classify-export --fuse-with``) answers with the softmax of its heads' mean
log-probability, every head on every call. Most views need only the first: where its top
probability is high, the fused answer is almost always the same (docs/classification.md). The
cascade keeps the canonicaliser and the first head in the graph, and puts the other heads and
the fusion behind an ONNX ``If``:

* every row (look) of the batch at or above ``threshold``: the first head's probabilities,
  and the other heads do not run;
* any row below it: the other heads run for the batch, and each row gets the fused answer if
  it is below the threshold, the first head's if it is not (a ``Where``): a row's answer never
  depends on the other rows of its batch.

The torch reference is ``cascade_probabilities``; the graph's card says ``cascade``.
"""

from __future__ import annotations

from collections.abc import Sequence

import onnx
import torch
from onnx import TensorProto, helper
from torch import Tensor

from itnet.model.classify.network import Classifier


def cascade_probabilities(nets: Sequence[Classifier], points: Tensor, threshold: float) -> Tensor:
    """Torch's answer of a cascade graph: points (B, N, 3) -> (B, C): the first net's softmax
    where its top probability is at least ``threshold``, the nets' fused answer elsewhere."""
    from itnet.export.classifier_export import fused_probabilities

    first = torch.softmax(nets[0].eval()(points)[0], dim=-1)
    sure = first.max(dim=-1, keepdim=True).values >= threshold
    return torch.where(sure, first, fused_probabilities(nets, points))


def _producers(graph: onnx.GraphProto) -> dict[str, onnx.NodeProto]:
    return {out: node for node in graph.node for out in node.output}


def _ancestors(graph: onnx.GraphProto, tensor: str) -> set[int]:
    """Indices of the nodes ``tensor`` is computed from (itself's producer included)."""
    producers = _producers(graph)
    index = {id(node): k for k, node in enumerate(graph.node)}
    seen: set[int] = set()
    stack = [tensor]
    while stack:
        node = producers.get(stack.pop())
        if node is None or index[id(node)] in seen:
            continue
        seen.add(index[id(node)])
        stack.extend(node.input)
    return seen


def _first_head_log_probabilities(graph: onnx.GraphProto) -> str:
    """The fused tail Softmax(ReduceMean(Concat(Unsqueeze(LogSoftmax(head)), ...))) -> the
    first head's LogSoftmax output. Raises ValueError for a graph of another form."""
    producers = _producers(graph)

    def made_by(tensor: str, op: str) -> onnx.NodeProto:
        node = producers.get(tensor)
        if node is None or node.op_type != op:
            found = "an input" if node is None else node.op_type
            raise ValueError(f"not a fused classifier graph: {tensor} is {found}, not {op}")
        return node

    softmax = made_by(graph.output[0].name, "Softmax")
    concat = made_by(made_by(softmax.input[0], "ReduceMean").input[0], "Concat")
    if len(concat.input) < 2:
        raise ValueError("not a fused classifier graph: one head, nothing to cascade")
    return made_by(made_by(concat.input[0], "Unsqueeze").input[0], "LogSoftmax").output[0]


def cascade_graph(model: onnx.ModelProto, threshold: float) -> onnx.ModelProto:
    """A fused classifier graph -> its cascade at ``threshold`` (see the module); the input,
    output and metadata unchanged. Raises ValueError for a graph that is not a fused one."""
    if not 0.0 < threshold <= 1.0:
        raise ValueError(f"the cascade's threshold must be in (0, 1], got {threshold}")
    graph = model.graph
    first = _first_head_log_probabilities(graph)
    kept = _ancestors(graph, first)
    main = [node for k, node in enumerate(graph.node) if k in kept]
    behind = [node for k, node in enumerate(graph.node) if k not in kept]
    output = graph.output[0]
    fused = output.name + "_fused"
    for node in behind:  # the fused answer, inside the branch, under another name
        node.output[:] = [fused if name == output.name else name for name in node.output]
    moved = {name for node in behind for name in node.output}
    classes = output.type.tensor_type.shape.dim[1]
    probs_type = helper.make_tensor_type_proto(TensorProto.FLOAT, ["batch", classes.dim_value])

    def typed(name: str) -> onnx.ValueInfoProto:
        return helper.make_value_info(name, probs_type)

    then_branch = helper.make_graph(
        [
            *behind,
            helper.make_node(
                "Where", ["cascade_sure", "cascade_first", fused], ["cascade_then"], "cascade_where"
            ),
        ],
        "other_heads",
        [],
        [typed("cascade_then")],
        value_info=[v for v in graph.value_info if v.name in moved],
    )
    else_branch = helper.make_graph(
        [helper.make_node("Identity", ["cascade_first"], ["cascade_else"], "cascade_identity")],
        "first_head_alone",
        [],
        [typed("cascade_else")],
    )
    main += [
        helper.make_node("Exp", [first], ["cascade_first"], "cascade_exp"),
        helper.make_node(
            "ReduceMax",
            ["cascade_first", "cascade_axis"],
            ["cascade_top"],
            "cascade_top",
            keepdims=1,
        ),
        helper.make_node(
            "GreaterOrEqual", ["cascade_top", "cascade_threshold"], ["cascade_sure"], "cascade_sure"
        ),
        helper.make_node(
            "ReduceMin", ["cascade_top"], ["cascade_least"], "cascade_least", keepdims=0
        ),
        helper.make_node(
            "Less", ["cascade_least", "cascade_threshold"], ["cascade_unsure"], "cascade_unsure"
        ),
        helper.make_node(
            "If",
            ["cascade_unsure"],
            [output.name],
            then_branch=then_branch,
            else_branch=else_branch,
        ),
    ]
    constants = [
        helper.make_tensor("cascade_threshold", TensorProto.FLOAT, [], [threshold]),
        helper.make_tensor("cascade_axis", TensorProto.INT64, [1], [1]),
    ]
    made = helper.make_graph(
        main,
        graph.name,
        list(graph.input),
        list(graph.output),
        initializer=[*graph.initializer, *constants],
        value_info=[v for v in graph.value_info if v.name not in moved],
    )
    cascaded = helper.make_model(made, opset_imports=list(model.opset_import))
    cascaded.ir_version = model.ir_version
    cascaded.metadata_props.extend(model.metadata_props)
    onnx.checker.check_model(cascaded)
    return cascaded
