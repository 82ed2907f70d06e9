"""A fused classifier graph made a cascade (export/cascade.py): the other heads run only for
looks whose first head is unsure, each look's answer as torch's cascade gives it."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from cls_helpers import CLASSES, randomised, tiny_classifier

from itnet.export.cascade import cascade_graph, cascade_probabilities
from itnet.export.classifier_export import export_classifier, fused_probabilities
from itnet.model_card import ClassifierCard
from itnet.pose.runtime import LoadedClassifier, load_any


@pytest.fixture(scope="module")
def heads() -> list[torch.nn.Module]:
    """A PointNet head first, a local head behind the same canonicaliser."""
    pointnet = randomised(tiny_classifier("itnet", 2), 6)
    local = randomised(
        tiny_classifier("itnet", 2, head="local", local_channels=(8, 16, 32), neighbours=5), 5
    )
    local.itnet.load_state_dict(pointnet.itnet.state_dict())
    return [pointnet, local]


@pytest.fixture(scope="module")
def fused_graph(heads, tmp_path_factory: pytest.TempPathFactory) -> Path:
    card = ClassifierCard(classes=CLASSES, points=100, head="pointnet+local")
    path = tmp_path_factory.mktemp("cascade") / "fused.onnx"
    return export_classifier(heads[0], card, path, fused=heads[1:])


def _cascaded(fused_graph: Path, threshold: float, out: Path) -> LoadedClassifier:
    onnx.save(cascade_graph(onnx.load(str(fused_graph)), threshold), str(out))
    loaded = load_any(out, warm_up=False)
    assert isinstance(loaded, LoadedClassifier)
    return loaded


def test_each_look_gets_the_first_head_where_sure_and_the_fused_answer_elsewhere(
    heads, fused_graph: Path, tmp_path: Path
) -> None:
    x = torch.randn(12, 100, 3, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        first = torch.softmax(heads[0](x)[0], -1).numpy()
        fused = fused_probabilities(heads, x).numpy()
    threshold = float(np.median(first.max(1)))  # half the looks sure, half not
    sure = first.max(1) >= threshold
    assert 0 < sure.sum() < len(sure)
    graph = _cascaded(fused_graph, threshold, tmp_path / "c.onnx")
    got = graph.probabilities(x.numpy())
    with torch.no_grad():
        want = cascade_probabilities(heads, x, threshold).numpy()
    np.testing.assert_allclose(got, want, atol=2e-5)
    np.testing.assert_allclose(got[sure], first[sure], atol=2e-5)
    np.testing.assert_allclose(got[~sure], fused[~sure], atol=2e-5)
    assert np.abs(fused[sure] - first[sure]).max() > 1e-3  # the two answers differ there
    # a look's answer does not depend on its batch: each alone gives the same
    alone = np.concatenate([graph.probabilities(x[i : i + 1].numpy()) for i in range(len(x))])
    np.testing.assert_allclose(alone, got, atol=2e-5)


def _nodes_run(path: Path, x: np.ndarray) -> set[str]:
    """Names of the graph nodes onnxruntime ran for ``x`` (its profile; optimisations off,
    so the names are the graph's)."""
    options = ort.SessionOptions()
    options.enable_profiling = True
    options.profile_file_prefix = str(path.parent / "profile")
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    session.run(None, {"points": x})
    profile = Path(session.end_profiling())
    events = json.loads(profile.read_text())
    os.remove(profile)
    suffix = "_kernel_time"
    return {e["name"][: -len(suffix)] for e in events if e["name"].endswith(suffix)}


def test_the_other_heads_do_not_run_when_every_look_is_sure(
    fused_graph: Path, tmp_path: Path
) -> None:
    path = tmp_path / "c.onnx"
    graph = cascade_graph(onnx.load(str(fused_graph)), 0.5)
    onnx.save(graph, str(path))
    (branch,) = [n for n in graph.graph.node if n.op_type == "If"]
    behind = {n.name for a in branch.attribute if a.name == "then_branch" for n in a.g.node}
    assert any("TopK" in n.op_type for a in branch.attribute for n in a.g.node)  # local head
    x = np.random.default_rng(4).normal(size=(1, 100, 3)).astype(np.float32)
    always = tmp_path / "always.onnx"  # threshold 1: every look is unsure
    onnx.save(cascade_graph(onnx.load(str(fused_graph)), 1.0), str(always))
    assert behind <= _nodes_run(always, x)
    never = tmp_path / "never.onnx"  # a threshold every look reaches
    onnx.save(cascade_graph(onnx.load(str(fused_graph)), 1e-9), str(never))
    ran = _nodes_run(never, x)
    assert ran and not (behind & ran)


def test_only_a_fused_graph_cascades(heads, fused_graph: Path, tmp_path: Path) -> None:
    single = export_classifier(
        heads[0], ClassifierCard(classes=CLASSES, points=100), tmp_path / "one.onnx"
    )
    with pytest.raises(ValueError, match="not a fused classifier graph"):
        cascade_graph(onnx.load(str(single)), 0.9)
    with pytest.raises(ValueError, match="threshold"):
        cascade_graph(onnx.load(str(fused_graph)), 0.0)
    kept = cascade_graph(onnx.load(str(fused_graph)), 0.9)
    original = onnx.load(str(fused_graph))
    assert {p.key: p.value for p in kept.metadata_props} == {
        p.key: p.value for p in original.metadata_props
    }  # the card rides along
    assert [i.name for i in kept.graph.input] == ["points"]
    assert [o.name for o in kept.graph.output] == ["probabilities"]
