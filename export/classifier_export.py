"""Export a trained classifier, canonicaliser included, to one ONNX graph:
normalised points (B, N, 3) -> class probabilities (B, C).

The IT-Net canonicaliser's steps are ``ExportableStep`` (the pose models' graph), unrolled; the
T-Net and the classifier are folded the same way (BatchNorm into the weights, channels-first
per-point MLP, max-pool over the innermost axis). Dropout is the identity at inference.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor, nn

from itnet.export.onnx_export import save_with_card
from itnet.model.classify.local import LocalHead, nearest_neighbours, neighbour_max
from itnet.model.classify.network import Classifier, PointNetHead, transformer_state
from itnet.model.network import ExportableStep, _bn_scale, _folded, _folded_mlp
from itnet.model_card import ClassifierCard, VerifierCard
from itnet.upright import UPRIGHT_EVAL_DEG

if TYPE_CHECKING:
    from itnet.pose.runtime import LoadedClassifier


def _constants(tensors: list[Tensor]) -> nn.ParameterList:
    """Tensors -> a ParameterList that no optimiser trains (the folded graph's constants)."""
    return nn.ParameterList([nn.Parameter(t, requires_grad=False) for t in tensors])


def _dense(g: Tensor, weights: nn.ParameterList, biases: nn.ParameterList) -> Tensor:
    """Pooled features (B, C) through the folded MLP: ReLU after every layer but the last."""
    for i, (w, b) in enumerate(zip(weights, biases)):
        g = g @ w + b
        if i < len(weights) - 1:
            g = torch.relu(g)
    return g


def _folded_dense(head: PointNetHead | LocalHead) -> tuple[nn.ParameterList, nn.ParameterList]:
    """A head's MLP after pooling and its output layer, folded: (weights (C_in, C_out), biases)."""
    dense = [*_folded_mlp(head.head), _folded(head.out, None)]
    return _constants([w.t().contiguous() for w, _ in dense]), _constants([b for _, b in dense])


class FoldedPointNet(nn.Module):
    """A ``PointNetHead`` in eval mode, folded for inference engines: (B, N, 3) -> (B, outputs)."""

    def __init__(self, head: PointNetHead) -> None:
        super().__init__()
        point = _folded_mlp(head.point_mlp)
        self.point_w = _constants([w for w, _ in point])
        self.point_b = _constants([b[:, None] for _, b in point])
        self.dense_w, self.dense_b = _folded_dense(head)

    def forward(self, points: Tensor) -> Tensor:
        h = points.transpose(1, 2)  # (B, 3, N)
        for w, b in zip(self.point_w[:-1], self.point_b[:-1]):
            h = torch.relu(w @ h + b)
        # max over points commutes with the per-channel bias and ReLU (see ExportableStep)
        g = torch.relu((self.point_w[-1] @ h).amax(dim=-1) + self.point_b[-1][:, 0])
        return _dense(g, self.dense_w, self.dense_b)


class FoldedLocalHead(nn.Module):
    """A ``LocalHead`` in eval mode, folded for inference engines: (B, N, 3) -> (B, outputs).

    Each neighbour layer's BatchNorm scale goes into its centre product and multiplies the
    neighbours' max (a negative scale would turn a max into a min if it went inside); the
    embedding runs channels-first so that its max-pool reduces the innermost axis, as in
    ``FoldedPointNet``.
    """

    def __init__(self, head: LocalHead) -> None:
        super().__init__()
        self.neighbours = head.neighbours
        folded = [_folded(layer.centre, layer.norm) for layer in head.layers]  # (s A, t)
        self.centre = _constants([w.t().contiguous() for w, _ in folded])
        self.shift = _constants([t for _, t in folded])
        self.neighbour = _constants(
            [layer.neighbour.weight.detach().float().t().contiguous() for layer in head.layers]
        )
        self.scale = _constants([_bn_scale(layer.norm) for layer in head.layers])
        (embed_w, embed_b), *_ = _folded_mlp(head.embed)
        self.embed_w = nn.Parameter(embed_w, requires_grad=False)  # (E, sum of the layers')
        self.embed_b = nn.Parameter(embed_b[:, None], requires_grad=False)
        self.dense_w, self.dense_b = _folded_dense(head)

    def forward(self, points: Tensor) -> Tensor:
        neighbours = nearest_neighbours(points, self.neighbours)
        x, layers = points, []
        for a, b, s, t in zip(self.centre, self.neighbour, self.scale, self.shift):
            x = torch.relu(x @ a + neighbour_max(x @ b, neighbours) * s + t)
            layers.append(x)
        h = torch.cat(layers, dim=-1).transpose(1, 2)  # (B, C, N)
        embedded = torch.relu(self.embed_w @ h + self.embed_b)  # (B, E, N)
        g = torch.cat([embedded.amax(dim=-1), embedded.mean(dim=-1)], dim=-1)
        return _dense(g, self.dense_w, self.dense_b)


def folded_head(head: PointNetHead | LocalHead) -> nn.Module:
    """The inference form of a classifier head."""
    return FoldedLocalHead(head) if isinstance(head, LocalHead) else FoldedPointNet(head)


class ExportableClassifier(nn.Module):
    """``Classifier`` in eval mode as one graph: points (B, N, 3) -> probabilities (B, C).

    ``canonical_points`` K: the transformer finds the pose from the first K points only (the
    runtime feeds a random order), and moves all N for the classifier. The canonicaliser's
    passes cost in proportion to their points, and it needs fewer than the classifier: on
    validation views, K = 96 of 256 cost 0.3-0.5 points of top-1, within the noise of which
    points are drawn, for about a quarter less time per request (docs/classification.md).

    ``fused``: classifiers with the same transformer weights (heads trained behind one frozen
    canonicaliser, ``classify-train --freeze-transformer``) whose heads read the same moved
    points; the graph's probabilities are then the softmax of the heads' mean log-probability
    (``fused_probabilities``), as the service fuses several looks.
    """

    def __init__(
        self, net: Classifier, canonical_points: int | None = None, fused: Sequence[Classifier] = ()
    ) -> None:
        super().__init__()
        net = net.eval()
        for other in fused:
            if not same_transformer(net, other):
                raise ValueError("fused classifiers must share the transformer's weights")
        self.canonical_points = canonical_points
        self.iterations = net.config.iterations
        self.step = ExportableStep(net.itnet) if net.itnet is not None else None
        self.tnet = FoldedPointNet(net.tnet.regressor) if net.tnet is not None else None
        self.heads = nn.ModuleList(folded_head(n.eval().classifier) for n in (net, *fused))

    def forward(self, points: Tensor) -> Tensor:
        moved = points
        seen = points if self.canonical_points is None else points[:, : self.canonical_points]
        if self.step is not None:
            pose = torch.eye(4, dtype=points.dtype).expand(points.shape[0], 4, 4)
            for _ in range(self.iterations):
                pose, _ = self.step(seen, pose)
            moved = points @ pose[:, :3, :3].transpose(1, 2) + pose[:, None, :3, 3]
        elif self.tnet is not None:
            total = torch.eye(3, dtype=points.dtype).expand(points.shape[0], 3, 3)
            for _ in range(self.iterations):
                update = self.tnet(seen @ total.transpose(1, 2)).reshape(-1, 3, 3)
                total = update @ total
            moved = points @ total.transpose(1, 2)
        if len(self.heads) == 1:
            return torch.softmax(self.heads[0](moved), dim=-1)
        logs = [torch.log_softmax(head(moved), dim=-1) for head in self.heads]
        return torch.softmax(torch.stack(logs).mean(dim=0), dim=-1)


def same_transformer(net: Classifier, other: Classifier) -> bool:
    """Do two classifiers hold the same transformer (weights and BatchNorm statistics)?"""
    mine, theirs = transformer_state(net.state_dict()), transformer_state(other.state_dict())
    return mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)


def fused_probabilities(nets: Sequence[Classifier], points: Tensor) -> Tensor:
    """Torch's answer of a fused graph: points (B, N, 3) -> softmax of the nets' mean
    log-probability (B, C) (one net: its probabilities)."""
    logs = torch.stack([torch.log_softmax(n.eval()(points)[0], dim=-1) for n in nets])
    return torch.softmax(logs.mean(dim=0), dim=-1)


def heads_name(nets: Sequence[Classifier]) -> str:
    """The card's ``head``: the fused heads' kinds, e.g. "local+pointnet"."""
    return "+".join(n.config.head for n in nets)


def export_classifier(
    net: Classifier,
    card: ClassifierCard,
    path: Path,
    opset: int = 20,
    fused: Sequence[Classifier] = (),
) -> Path:
    """Write ``path`` (.onnx): the classifier graph (``fused``: more heads behind the same
    canonicaliser, see ``ExportableClassifier``) with ``card`` as metadata. Returns the path."""
    if len(card.classes) != net.config.classes:
        raise ValueError(
            f"the card names {len(card.classes)} classes, the net has {net.config.classes}"
        )
    graph = ExportableClassifier(net, card.canonical_points, fused).eval()
    return export_points_graph(graph, "probabilities", card, path, opset)


def export_points_graph(
    graph: nn.Module,
    output: str,
    card: ClassifierCard | VerifierCard,
    path: Path,
    opset: int = 20,
) -> Path:
    """Write ``path`` (.onnx): a graph of points (B, N, 3) -> ``output``, any B and N, with
    ``card`` as metadata (the classifier's and the verifier's). Returns the path."""
    batch, count = torch.export.Dim("batch", min=1, max=4096), torch.export.Dim("points", min=1)
    program = torch.onnx.export(
        graph.eval(),
        (torch.randn(2, 64, 3),),
        dynamo=True,
        opset_version=opset,
        input_names=["points"],
        output_names=[output],
        dynamic_shapes={"points": {0: batch, 1: count}},
        external_data=False,
        verbose=False,
    )
    return save_with_card(program.model_proto, card, path)  # type: ignore[union-attr]


def choose_threshold(
    max_probability: list[float], correct: list[bool], target: float = 0.95
) -> float:
    """The lowest probability threshold (0.05 steps) at which the validation views at or above
    it are at least ``target`` correct: below it, a recognition is reported as unsure. 0 when
    every view already is; 0.95 when no threshold reaches the target."""
    p, ok = np.asarray(max_probability), np.asarray(correct, dtype=bool)
    for threshold in np.arange(0.0, 0.951, 0.05):
        sure = p >= threshold
        if sure.any() and ok[sure].mean() >= target:
            return round(float(threshold), 2)
    return 0.95


@dataclass
class GraphScores:
    """An exported classifier graph's probabilities on a run's fixed views: validation (V, C)
    with labels (V,), test (T, C) with labels (T,)."""

    val_probs: NDArray[np.float64]
    val_labels: NDArray[np.int64]
    test_probs: NDArray[np.float64]
    test_labels: NDArray[np.int64]


def score_graph(
    model: LoadedClassifier, run: Path, beside: LoadedClassifier | None = None
) -> GraphScores:
    """Run an exported graph over the run's fixed validation and test views, one view per call
    as the service runs it (an int8 graph quantises its activations with one scale per call),
    each cut to the graph's card's points where it is served at fewer than trained.
    ``beside`` (an upright run's graph): served fused with this classifier for any orientation
    (``itnet/pose/recognition.py``), so each view's probabilities are the two's, averaged in the
    log domain, ``beside`` seeing the same points unlevelled."""
    from itnet.model.classify.train import ClassifyConfig, run_splits, run_views
    from itnet.pose.recognition import mean_log_probability

    config = ClassifyConfig.model_validate_json((run / "config.json").read_text())
    _, splits = run_splits(config)
    scored = []
    for split in ("val", "test"):
        x, y = run_views(config, splits, split)
        x = x[:, : model.card.points]  # served at fewer points: as many (a view's are shuffled)
        probs = np.concatenate([model.probabilities(x[i : i + 1]) for i in range(len(x))])
        if beside is not None:
            free, labels = run_views(config.model_copy(update={"upright": None}), splits, split)
            free = free[:, : beside.card.points]
            assert (labels == y).all()
            other = np.concatenate([beside.probabilities(free[i : i + 1]) for i in range(len(x))])
            fused = mean_log_probability([other, probs])
            probs = np.exp(fused - fused.max(1, keepdims=True))
            probs /= probs.sum(1, keepdims=True)
        scored += [probs.astype(np.float64), y]
    return GraphScores(*scored)


def card_from_run(
    run: Path,
    scores: GraphScores,
    points: int | None = None,
    target: float = 0.95,
    beside: str | None = None,
) -> ClassifierCard:
    """The card of a finished run's exported graph: classes and training from the run, test
    accuracy and the unsure threshold (chosen on the validation views) from ``scores``
    (``beside``: the name of the classifier they were fused with, see :func:`score_graph`)."""
    from itnet.model.classify.train import metrics

    result = json.loads((run / "result.json").read_text())
    config = json.loads((run / "config.json").read_text())
    test = metrics(scores.test_probs, scores.test_labels, result["classes"])
    val = metrics(scores.val_probs, scores.val_labels, result["classes"])
    correct = scores.val_probs.argmax(1) == scores.val_labels
    threshold = choose_threshold(list(scores.val_probs.max(1)), list(correct), target)
    upright = config.get("upright") is not None  # trained on levelled views
    views = (
        f"levelled by their up direction {UPRIGHT_EVAL_DEG:g} deg off the truth (yaw free)"
        if upright
        else "full SO(3)"
    )
    rules = config.get("views") or ["occluded", "paper"]
    kinds = (
        "half occluded, half the paper's z-buffer"
        if sorted(rules) == ["occluded", "paper"]
        else " and ".join(rules) + " views alike"
    )
    if config.get("elevation") is not None:
        low, high = config["elevation"]
        views += f"; cameras {low:g} to {high:g} deg over the object's horizon"
    if beside is not None:  # what the accuracy and the threshold are of
        views += f"; fused with {beside} on the unlevelled view, as served"
    return ClassifierCard(
        classes=result["classes"],
        points=points or trained_points(run),
        transformer=result["variant"],
        threshold=threshold,
        upright=upright,
        accuracy=round(test["accuracy"], 4),
        mean_class_accuracy=round(test["mean_class_accuracy"], 4),
        evaluation=(
            f"{test['scans']} partial views ({kinds}; {views}, "
            f"noise) of the ModelNet10 test split, {config['points']} points, measured "
            f"on this graph one view per call; standard error "
            f"{100 * test['standard_error']:.1f} points; threshold: the lowest at which "
            f"{100 * target:.0f}% of the validation views above it are right"
        ),
        training={
            "steps": result["best_step"],
            "batch": config["batch"],
            "lr": config["lr"],
            "decay_every": config["decay_every"],
            "validation": round(val["accuracy"], 4),
        },
    )


def trained_points(run: Path) -> int:
    """Points per view the run trained with (its config.json)."""
    return int(json.loads((run / "config.json").read_text())["points"])


def unsure_split(scores: GraphScores, threshold: float) -> dict[str, float]:
    """The threshold on the test views: the share reported unsure, and the top-1 accuracy of
    the sure and the unsure views."""
    probs, y = scores.test_probs, scores.test_labels
    sure, correct = probs.max(1) >= threshold, probs.argmax(1) == y
    return {
        "threshold": threshold,
        "test_views": len(y),
        "unsure_share": round(float(1 - sure.mean()), 4),
        "sure_accuracy": round(float(correct[sure].mean()), 4) if sure.any() else float("nan"),
        "unsure_accuracy": round(float(correct[~sure].mean()), 4)
        if (~sure).any()
        else float("nan"),
        "accuracy": round(float(correct.mean()), 4),
    }
