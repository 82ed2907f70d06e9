"""The local classifier head: its neighbours, its neighbour max (trained one way, exported
another), and a run that trains it behind a frozen canonicaliser taken from another run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from cls_helpers import tiny_run

from itnet.model.classify.local import LocalHead, nearest_neighbours, neighbour_max
from itnet.model.classify.train import load_classifier, train


def test_nearest_neighbours_are_the_closest_points() -> None:
    points = torch.randn(2, 50, 3, generator=torch.Generator().manual_seed(0))
    got = nearest_neighbours(points, 6).numpy()
    assert got.shape == (2, 50, 6)
    for b in range(2):
        p = points[b].numpy()
        distances = np.linalg.norm(p[:, None] - p[None], axis=-1)
        want = np.argsort(distances, axis=1)[:, :6]
        np.testing.assert_array_equal(np.sort(got[b], 1), np.sort(want, 1))
        assert (got[b][:, 0] == np.arange(50)).all()  # each point is its own nearest
    assert nearest_neighbours(points[:, :4], 6).shape == (2, 4, 4)  # k clamped to N


def test_neighbour_max_trains_and_infers_the_same_function() -> None:
    """The training path (winners found without a gradient, then read with one) gives the
    values and the gradient of the plain gather-and-max that the exported graph computes."""
    gen = torch.Generator().manual_seed(1)
    features = torch.randn(3, 20, 5, generator=gen, requires_grad=True)
    neighbours = torch.randint(0, 20, (3, 20, 4), generator=gen)
    weights = torch.randn(3, 20, 5, generator=gen)
    fast = neighbour_max(features, neighbours)
    (fast * weights).sum().backward()
    fast_grad = features.grad.clone()
    features.grad = None
    dense = torch.stack(
        [features[b][neighbours[b]].amax(dim=1) for b in range(3)]
    )  # (B, N, C) by the definition
    (dense * weights).sum().backward()
    torch.testing.assert_close(fast, dense)
    torch.testing.assert_close(fast_grad, features.grad)
    with torch.no_grad():
        torch.testing.assert_close(neighbour_max(features, neighbours), dense)


def test_local_head_sees_where_a_point_sits_among_its_neighbours() -> None:
    """Unlike a PointNet head, two clouds with the same points' own coordinates up to one
    neighbourhood differ: moving one point changes its neighbours' features (a max over them)."""
    torch.manual_seed(0)
    head = LocalHead(3, (8, 8, 16), (8,), neighbours=4).eval()
    cloud = torch.randn(1, 30, 3)
    moved = cloud.clone()
    moved[0, 0] += 0.3
    with torch.no_grad():
        assert not torch.allclose(head(cloud), head(moved))
        shuffled = cloud[:, torch.randperm(30)]
        torch.testing.assert_close(head(cloud), head(shuffled))  # order does not matter


@pytest.mark.train
def test_a_local_head_trains_behind_a_frozen_transformer(
    three_classes: Path,
    tmp_path: Path,
) -> None:
    """``transformer_from`` copies a run's canonicaliser, ``freeze_transformer`` keeps it (weights
    and BatchNorm statistics); the local head learns; the export card names the head."""
    import onnx
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.pose.runtime import LoadedClassifier, load_any

    source = tiny_run(three_classes, tmp_path / "source", steps=20, eval_every=20)
    train(source)
    config = tiny_run(
        three_classes, tmp_path / "local", steps=30, eval_every=15, head="local", neighbours=6,
        local_channels=(8, 16, 32), transformer_from=source.out / "best.pt",
        freeze_transformer=True, hold_test=True,
    )  # fmt: skip
    train(config)
    before, _ = load_classifier(source.out / "best.pt")
    after, _ = load_classifier(config.out / "last.pt")
    kept = {k: v for k, v in before.state_dict().items() if k.startswith("itnet.")}
    for name, value in after.state_dict().items():
        if name.startswith("itnet."):
            torch.testing.assert_close(value, kept[name], msg=name)
    assert isinstance(after.classifier, LocalHead)
    log = [json.loads(line) for line in (config.out / "log.jsonl").read_text().splitlines()]
    losses = [e["loss"] for e in log if "loss" in e]
    assert losses[-1] < losses[0]
    out = tmp_path / "local.onnx"
    run = CliRunner().invoke(app, ["classify-export", str(config.out), "--out", str(out)])
    assert run.exit_code == 0, run.output
    graph = load_any(out, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.head == "local"
    # the source run's head shares the canonicaliser: the two export fused, measured as one
    fused = tmp_path / "fused.onnx"
    both = [str(config.out), "--out", str(fused), "--fuse-with", str(source.out / "best.pt")]
    run = CliRunner().invoke(app, ["classify-export", *both])
    assert run.exit_code == 0, run.output
    graph = load_any(fused, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.head == "local+pointnet"
    assert graph.card.training["fused_with"] == ["best.pt"] and 0 <= graph.card.accuracy <= 1
    assert graph.card.cascade is None
    # the cascade: the same heads, the second only where the first is unsure; said on the card
    cascaded = tmp_path / "cascade.onnx"
    run = CliRunner().invoke(app, ["classify-export", *both[:1], "--out", str(cascaded),
                                   *both[3:], "--cascade", "0.8"])  # fmt: skip
    assert run.exit_code == 0, run.output
    graph = load_any(cascaded, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.cascade == 0.8
    assert any(n.op_type == "If" for n in onnx.load(str(cascaded)).graph.node)
    for refused in (["--cascade", "0.8"], [*both[3:], "--cascade", "0.8", "--int8"]):
        run = CliRunner().invoke(app, ["classify-export", str(config.out), "--out",
                                       str(tmp_path / "no.onnx"), *refused])  # fmt: skip
        assert run.exit_code == 2 and "--cascade" in run.output
    other = tiny_run(three_classes, tmp_path / "other", steps=5, eval_every=5, init_seed=3)
    train(other)  # another canonicaliser: refused
    run = CliRunner().invoke(
        app, ["classify-export", str(config.out), "--out", str(tmp_path / "no.onnx"),
              "--fuse-with", str(other.out / "best.pt")],
    )  # fmt: skip
    assert run.exit_code == 2 and "share the transformer" in run.output


@pytest.mark.train
def test_transformer_weights_must_fit(three_classes: Path, tmp_path: Path) -> None:
    source = tiny_run(three_classes, tmp_path / "source", steps=5, eval_every=5, hold_test=True)
    train(source)
    wider = tiny_run(
        three_classes, tmp_path / "wider", steps=5, head="local",
        widths=((16, 32, 128), (32, 16)), transformer_from=source.out / "best.pt",
    )  # fmt: skip
    with pytest.raises(RuntimeError, match="size mismatch"):
        train(wider)
    none = tiny_run(three_classes, tmp_path / "none", steps=5, variant="none",
                    freeze_transformer=True)  # fmt: skip
    with pytest.raises(ValueError, match="no transformer"):
        train(none)
