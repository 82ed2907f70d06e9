"""Training one classifier variant: cross-entropy only, validation, checkpoints, resume, test.

A run folder holds ``config.json``, ``log.jsonl`` (one line per logged step, validation lines
included), ``last.pt`` (resume), ``best.pt`` (best validation accuracy) and, once finished,
``result.json`` (validation and test metrics of ``best.pt``; the test split is evaluated once,
after training, never used for a choice).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pydantic import BaseModel
from torch import nn
from torch.optim.swa_utils import AveragedModel

from itnet.atomic_write import written_whole
from itnet.model.classify.data import (
    LabelledShapes,
    class_names,
    fixed_views,
    load_splits,
    shuffled_views,
    training_batch,
    view_configs,
)
from itnet.model.classify.network import (
    TRANSFORMER_PREFIXES,
    VARIANTS,
    Classifier,
    ClassifierConfig,
    transformer_state,
)
from itnet.model.optim import (
    CompiledForward,
    average_of,
    bn_momentum,
    learning_rate,
    prepare_cpu,
    set_schedule,
)
from itnet.model.prefetch import Prefetcher
from itnet.upright import UPRIGHT_EVAL_DEG


class ClassifyConfig(BaseModel):
    """Everything a run depends on; dumped to config.json and stored in every checkpoint."""

    data: Path = Path("../shared/data/modelnet10")
    variant: str = "itnet-2"
    out: Path = Path("runs/cls/itnet-2")
    cache: Path = Path("cache")
    steps: int = 1200
    batch: int = 32
    points: int = 256
    lr: float = 1e-3
    lr_decay: float = 0.7
    decay_every: int = 240
    bn_momentum: tuple[float, float] = (0.5, 0.01)  # start -> floor, halves every decay_every
    validation_fraction: float = 0.1
    val_views: int = 2
    test_views: int = 4
    eval_every: int = 200
    log_every: int = 25
    seed: int = 0  # the validation split, the fixed views, and (unless init_seed) the run's
    # the network's initialisation and the training batches; None: ``seed``. Another value trains
    # another network on the same split (a second member of an ensemble, validated alike)
    init_seed: int | None = None

    @property
    def run_seed(self) -> int:
        """The seed of the initialisation and the training batches."""
        return self.seed if self.init_seed is None else self.init_seed

    threads: int = 1
    # autocast matmuls to bfloat16, the transforms' math in fp32; None: where it pays (fast_bf16)
    bf16: bool | None = None
    widths: tuple[tuple[int, ...], tuple[int, ...]] | None = None  # (point, head) for tiny tests
    max_shapes_per_class: int | None = None  # tiny tests: a few shapes of each class
    init_from: Path | None = None  # start from these weights (a longer run of a table row)
    # classes weigh alike: drawn uniformly into the batches, best.pt chosen on the validation's
    # mean class accuracy (the test split is nearly balanced, the training split is not)
    balanced: bool = False
    # > 0: teach IT-Net to stand views up (``network.py``: the up-axis term; 0 = the paper's
    # class loss alone, as every row of the table)
    up_weight: float = 0.0
    # > 1: each training shape stretched along its axes by up to this factor (``data.py``)
    stretch: float = 1.0
    # not None: upright views (``data.py``), levelled by an up direction with up to this many
    # degrees of error in training, exactly ``UPRIGHT_EVAL_DEG`` in validation and test; the
    # classifier for requests that give ``up``
    upright: float | None = None
    # the view rules of training, validation and test (``model.scanner.VIEW_RULES``), and where
    # the camera may be: (min, max) degrees over the shape's horizon (a camera above the floor,
    # as scenes see furniture), None: any direction
    views: tuple[str, ...] = ("occluded", "paper")
    elevation: tuple[float, float] | None = None
    # the transformer finds its pose from this many of the points (ClassifierConfig); the
    # training and evaluation views are then fed in random order, as the service feeds them
    canonical_points: int | None = None
    # > 0: the cross-entropy's targets smoothed (1 - e on the class, e spread over all classes)
    label_smoothing: float = 0.0
    # not None: an exponential moving average of the weights and BatchNorm statistics (decay per
    # step), validated beside the raw weights; best.pt keeps whichever scores higher
    ema: float | None = None
    # the run ends without reading the test split (result.json's test is None): for experiments
    # whose choice is still open; ``itnet classify-export`` measures the exported graph on it
    hold_test: bool = False
    # the classifier after the transformer: "pointnet" or "local" (``local.LocalHead``, with
    # ``neighbours`` nearest points; either None: ClassifierConfig's default)
    head: str = "pointnet"
    neighbours: int | None = None
    local_channels: tuple[int, ...] | None = None
    # start the transformer (only) from this checkpoint's, e.g. a new head behind the shipped
    # canonicaliser; frozen: the transformer is not trained (eval mode, no gradient)
    transformer_from: Path | None = None
    freeze_transformer: bool = False
    compile: bool = False  # torch.compile the network for the training steps
    device: str = "cpu"  # cpu | cuda
    data_workers: int = 0  # processes making the batches ahead (model/prefetch.py; for a GPU)


def network_config(config: ClassifyConfig, classes: int) -> ClassifierConfig:
    base = VARIANTS[config.variant]
    widths = {}
    if config.widths is not None:
        widths = {"point_channels": config.widths[0], "head_channels": config.widths[1]}
    return ClassifierConfig(
        **{
            **vars(base),
            "classes": classes,
            **widths,
            "up_weight": config.up_weight,
            "canonical_points": config.canonical_points,
            "head": config.head,
            **{
                key: value
                for key in ("neighbours", "local_channels")
                if (value := getattr(config, key)) is not None
            },
        }
    )


def run_splits(config: ClassifyConfig) -> tuple[list[str], dict[str, LabelledShapes]]:
    """(class names, {'train', 'val', 'test'} -> labelled shapes) of a run: the dataset's split,
    validation carved from train, at most ``max_shapes_per_class`` per class if set."""
    classes = class_names(config.data)
    splits = load_splits(
        config.data, classes, config.validation_fraction, config.seed, config.cache
    )
    if config.max_shapes_per_class is not None:
        for split in splits.values():
            keep = np.concatenate(
                [
                    np.flatnonzero(split.labels == k)[: config.max_shapes_per_class]
                    for k in range(len(classes))
                ]
            )
            split.shapes, split.labels = [split.shapes[i] for i in keep], split.labels[keep]
    return classes, splits


def run_views(
    config: ClassifyConfig, splits: dict[str, LabelledShapes], split: str
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """A run's fixed 'val' or 'test' views (the same every time: seeded, cached, each view's
    points in a seeded random order) -> (points (V, N, 3), labels (V,))."""
    views, seed = {"val": (config.val_views, 7), "test": (config.test_views, 13)}[split]
    upright = None if config.upright is None else UPRIGHT_EVAL_DEG
    x, y = fixed_views(
        splits[split], views, config.points, config.seed + seed, config.cache, upright,
        view_configs(config.views, config.elevation),
    )  # fmt: skip
    # each view's points in random order, as the service feeds them: a small view's repeats
    # follow its points in scan order, and a transformer that reads only the first points
    # (``canonical_points``) must get a random sample of the view
    return shuffled_views(x, np.random.default_rng(config.seed + seed)), y


@torch.no_grad()
def predict(net: Classifier, x: NDArray[np.float32], batch: int = 256) -> NDArray[np.float64]:
    """Class probabilities (V, C) of normalised views (V, N, 3), eval mode."""
    net.eval()
    device = next(net.parameters()).device
    out = [
        torch.softmax(net(torch.from_numpy(x[i : i + batch]).to(device))[0].float(), -1).cpu()
        for i in range(0, len(x), batch)
    ]
    return torch.cat(out).double().numpy()


def metrics(probs: NDArray, labels: NDArray, classes: list[str]) -> dict:
    """Top-1 accuracy (+ standard error), per-class accuracy, mean class accuracy, confusion
    matrix (rows: true class, columns: predicted)."""
    predicted = probs.argmax(1)
    confusion = np.zeros((len(classes), len(classes)), dtype=np.int64)
    np.add.at(confusion, (labels, predicted), 1)
    correct = predicted == labels
    per_class = {
        name: float(correct[labels == k].mean())
        for k, name in enumerate(classes)
        if (labels == k).any()
    }
    accuracy = float(correct.mean())
    return {
        "accuracy": accuracy,
        "standard_error": math.sqrt(accuracy * (1 - accuracy) / len(labels)),
        "scans": len(labels),
        "mean_class_accuracy": float(np.mean(list(per_class.values()))),
        "per_class": per_class,
        "confusion": confusion.tolist(),
    }


def _save(
    path: Path,
    net: Classifier,
    opt,
    step: int,
    config: ClassifyConfig,
    extra: dict,
    ema: AveragedModel | None = None,
) -> None:
    """``net``'s weights as "model" (to ship or resume), and for resume the optimiser and, when
    given, the moving average."""
    state = {
        "model": net.state_dict(),
        **({"ema": ema.state_dict()} if ema is not None else {}),
        "optimizer": opt.state_dict(),
        "step": step,
        "config": config.model_dump(mode="json"),
        "network": vars(net.config),
        **extra,
    }
    with written_whole(path) as tmp:
        torch.save(state, tmp)


def load_classifier(path: Path) -> tuple[Classifier, dict]:
    """A trained classifier (eval mode, CPU) and its checkpoint dict."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in state["network"].items()}
    net = Classifier(ClassifierConfig(**fields))
    net.load_state_dict(state["model"])
    return net.eval(), state


def train(config: ClassifyConfig, log_progress: bool = False) -> dict:
    """Train (or resume) one variant; returns ``result.json``'s content (val + test of best.pt)."""
    bf16 = prepare_cpu(config.threads, config.bf16, config.device)
    config = config.model_copy(update={"bf16": bf16})
    config.out.mkdir(parents=True, exist_ok=True)
    (config.out / "config.json").write_text(config.model_dump_json(indent=2))
    classes, splits = run_splits(config)
    scan_configs = view_configs(config.views, config.elevation)
    val_x, val_y = run_views(config, splits, "val")

    def make_batch(step: int) -> tuple[NDArray[np.float32], NDArray[np.int64], NDArray]:
        rng = np.random.default_rng([config.run_seed, step])  # per-step stream: resume-exact data
        x, y, up = training_batch(
            splits["train"],
            config.batch,
            config.points,
            rng,
            scan_configs,
            config.balanced,
            config.stretch,
            config.upright,
        )
        if config.canonical_points is not None:  # a small view's repeats follow its scan order
            x = shuffled_views(x, rng)
        return x, y, up

    with Prefetcher(make_batch, config.data_workers) as prefetch:  # forks before CUDA starts
        return _train_loop(config, classes, splits, val_x, val_y, prefetch, log_progress)


def _train_loop(config: ClassifyConfig, classes: list[str], splits: dict[str, LabelledShapes],
                val_x: NDArray[np.float32], val_y: NDArray[np.int64], prefetch: Prefetcher,
                log_progress: bool) -> dict:  # fmt: skip
    torch.manual_seed(config.run_seed)
    net = Classifier(network_config(config, len(classes))).to(config.device)
    opt = torch.optim.Adam(
        [p for name, p in net.named_parameters() if not _frozen(config, name)], lr=config.lr
    )
    step, best = 0, {"val_accuracy": -1.0, "val_mean_class": -1.0}
    chosen_on = "val_mean_class" if config.balanced else "val_accuracy"
    last = config.out / "last.pt"
    if last.exists():
        state = torch.load(last, map_location=config.device, weights_only=False)
        net.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        step, best = state["step"], state["best"]
    elif config.init_from is not None:
        state = torch.load(config.init_from, map_location=config.device, weights_only=False)
        net.load_state_dict(state["model"])
    elif config.transformer_from is not None:
        load_transformer(net, config.transformer_from)
    frozen = frozen_transformer(net) if config.freeze_transformer else None
    ema = average_of(net, config.ema)  # starts at the weights the run starts from
    if ema is not None and last.exists() and "ema" in state:
        ema.load_state_dict(state["ema"])
    log = (config.out / "log.jsonl").open("a")

    def write(entry: dict) -> None:
        log.write(json.dumps(entry) + "\n")
        log.flush()
        if log_progress:
            print(json.dumps(entry), flush=True)

    write(
        {
            "event": "start",
            "step": step,
            "variant": config.variant,
            "train_shapes": len(splits["train"].shapes),
            "val_scans": len(val_y),
        }
    )
    losses: list[float] = []
    penalties: list[float] = []  # the transformer's extra terms (regulariser, up axis)
    started = time.time()
    forward = CompiledForward(net, config.compile)
    for x, y, up in prefetch.batches(step, config.steps):
        lr = learning_rate(config.lr, config.lr_decay, config.decay_every, step)
        set_schedule(net, opt, lr, bn_momentum(config.bn_momentum, config.decay_every, step))
        net.train()
        if frozen is not None:
            frozen.eval()
        x_t, y_t = torch.from_numpy(x).to(config.device), torch.from_numpy(y).to(config.device)
        up_t = torch.from_numpy(up).to(config.device) if config.up_weight else None
        with torch.autocast(x_t.device.type, dtype=torch.bfloat16, enabled=config.bf16):
            logits, penalty = forward(x_t, up_t)
        loss = (
            torch.nn.functional.cross_entropy(
                logits.float(), y_t, label_smoothing=config.label_smoothing
            )
            + penalty
        )
        penalties.append(float(penalty.detach()))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if ema is not None:
            ema.update_parameters(net)
        step += 1
        losses.append(float(loss.detach()))
        if not math.isfinite(losses[-1]):
            raise FloatingPointError(f"loss is not finite at step {step}")
        if step % config.log_every == 0:
            mean = float(np.mean(losses[-config.log_every :]))
            penalty_mean = float(np.mean(penalties[-config.log_every :]))
            write(
                {
                    "step": step,
                    "loss": mean,
                    "penalty": penalty_mean,
                    "lr": lr,
                    "seconds": round(time.time() - started, 1),
                }
            )
        if step % config.eval_every == 0 or step == config.steps:
            entry, chosen = _validated(net, val_x, val_y, classes, step, "raw"), net
            if ema is not None:  # the average competes with the raw weights on validation
                averaged = _validated(ema.module, val_x, val_y, classes, step, "ema")
                entry |= {f"raw_{k}": entry[k] for k in ("val_accuracy", "val_mean_class")}
                entry |= {f"ema_{k}": averaged[k] for k in ("val_accuracy", "val_mean_class")}
                if averaged[chosen_on] > entry[chosen_on]:
                    entry, chosen = {**entry, **averaged}, ema.module
            if entry[chosen_on] > best[chosen_on]:
                best = entry
                _save(
                    config.out / "best.pt",
                    chosen,
                    opt,
                    step,
                    config,
                    {"best": best, "classes": classes},
                )
            _save(last, net, opt, step, config, {"best": best, "classes": classes}, ema)
            write({"event": "val", **entry})
    result = evaluate_run(config, classes, splits, val_x, val_y)
    test = result["test"]
    write({"event": "done", "test_accuracy": test["accuracy"] if test else None})
    log.close()
    return result


def _frozen(config: ClassifyConfig, name: str) -> bool:
    return config.freeze_transformer and name.startswith(TRANSFORMER_PREFIXES)


def load_transformer(net: Classifier, checkpoint: Path) -> None:
    """Copy the transformer's weights (and BatchNorm statistics) of a classifier checkpoint of any
    head into ``net``; the shapes must match."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)["model"]
    wanted = transformer_state(state)
    if not wanted:
        raise ValueError(f"{checkpoint} holds no transformer weights")
    missing = [k for k in transformer_state(net.state_dict()) if k not in wanted]
    if missing:
        raise ValueError(f"{checkpoint} lacks the transformer's {missing[:3]}")
    net.load_state_dict(wanted, strict=False)


def frozen_transformer(net: Classifier) -> nn.Module:
    """Stop the gradient of ``net``'s transformer and return it (the training loop keeps it in
    eval mode, so its BatchNorm statistics stay too)."""
    transformer = net.itnet if net.itnet is not None else net.tnet
    if transformer is None:
        raise ValueError("this classifier has no transformer to freeze")
    return transformer.requires_grad_(False)


def _validated(
    net: Classifier, val_x: NDArray, val_y: NDArray, classes: list[str], step: int, weights: str
) -> dict:
    """One validation entry of the log: top-1 and mean class accuracy of ``net``."""
    val = metrics(predict(net, val_x), val_y, classes)
    return {
        "step": step,
        "weights": weights,
        "val_accuracy": val["accuracy"],
        "val_mean_class": val["mean_class_accuracy"],
    }


def evaluate_run(config: ClassifyConfig, classes: list[str], splits: dict, val_x, val_y) -> dict:
    """Validation and test metrics of the run's best.pt -> result.json (cached); ``test`` is
    None where the data has no test split (a training-only copy on a GPU machine) or the run
    holds it back (``hold_test``)."""
    path = config.out / "result.json"
    if path.exists():
        return json.loads(path.read_text())
    net, state = load_classifier(config.out / "best.pt")
    test = None
    if splits["test"].shapes and not config.hold_test:
        test_x, test_y = run_views(config, splits, "test")
        test = metrics(predict(net, test_x), test_y, classes)
    result = {
        "variant": config.variant,
        "classes": classes,
        "best_step": state["step"],
        "steps": config.steps,
        "val": metrics(predict(net, val_x), val_y, classes),
        "test": test,
    }
    path.write_text(json.dumps(result))
    return result


def run_of_checkpoint(
    checkpoint: Path, folder: Path, data: Path | None = None, cache: Path | None = None
) -> Path:
    """A shipped classifier checkpoint (``classify-export --weights-out``, which keeps the run's
    config) -> ``folder`` made a run folder of it, as its training left one: best.pt,
    config.json and result.json (torch's validation and test metrics, remeasured). What
    ``classify-export`` reads when the run itself is gone. ``data`` / ``cache``: where the
    dataset and the cache are here, for a checkpoint trained elsewhere (a GPU machine's paths).
    Returns ``folder``."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    if "config" not in state or "classes" not in state:
        raise ValueError(f"{checkpoint}: not a classifier checkpoint (no config or classes)")
    where = {k: v for k, v in (("data", data), ("cache", cache)) if v is not None}
    here = {"device": "cpu", **where}
    config = ClassifyConfig.model_validate({**state["config"], "out": folder, **here})
    folder.mkdir(parents=True, exist_ok=True)
    # the weights with the config of here: what is shipped from this folder (``classify-export
    # --weights-out``) then exports and fine-tunes here, not on the machine that trained it
    state["config"] = config.model_dump(mode="json")
    torch.save(state, folder / "best.pt")
    (folder / "config.json").write_text(config.model_dump_json(indent=2))
    classes, splits = run_splits(config)
    val_x, val_y = run_views(config, splits, "val")
    evaluate_run(config, classes, splits, val_x, val_y)
    return folder
