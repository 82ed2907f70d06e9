"""Training IT-Net: unrolled iterations, PLoss on the final pose, validation, checkpoints, resume.

Run it through ``itnet train``. A run folder holds ``config.json``, ``log.jsonl`` (one line per
logged step, validation lines included), ``last.pt`` (for resume) and ``best.pt`` (best
validation accuracy, the one to ship).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from pydantic import BaseModel, Field
from torch.optim.swa_utils import AveragedModel

from itnet.atomic_write import written_whole
from itnet.model.category_set import CategorySet, category_names, load_category_set
from itnet.model.data import NearStarts, training_batch
from itnet.model.evaluate import anytime_poses, report, torch_step
from itnet.model.network import ITNet, NetworkConfig, PointLoss, Rotation, point_loss
from itnet.model.optim import (
    CompiledForward,
    average_of,
    bn_momentum,
    learning_rate,
    prepare_cpu,
    set_schedule,
)
from itnet.model.prefetch import Prefetcher
from itnet.model.scanner import PAPER_VIEWS, scan_config
from itnet.model.widen import can_widen, widen
from itnet.upright import UPRIGHT_EVAL_DEG, sensed_ups


class TrainConfig(BaseModel):
    """Everything a run depends on; dumped to config.json and stored in every checkpoint."""

    data: Path = Path("../shared/data/modelnet10")
    category: str = "chair"  # one name, a comma list, or 'modelnet10' (every class of DATA)
    symmetry: str | None = None  # override the category table's symmetry (a user's category)
    frame: str = "modelnet"
    check_orientation: bool = True
    out: Path = Path("runs/chair")
    cache: Path = Path("cache")
    steps: int = 10000
    batch: int = 32
    points: int = 256
    eval_points: int = 256  # what the runtime feeds a model trained on 256 points
    iterations: int = 5
    loss: PointLoss = "squared"  # per point (network.point_loss)
    supervise_last: int = Field(1, ge=1)  # loss averaged over the last M iterations (all if more)
    eval_iterations: int = 10
    lr: float = 1e-3
    lr_decay: float = 0.7
    decay_every: int = 1250
    bn_momentum: tuple[float, float] = (
        0.5,
        0.01,
    )  # torch momentum, start -> end (TF decay 0.5 -> 0.99)
    bn_decay_every: int = 1250
    stop_gradient: bool = True
    identity_init: bool = True
    rotation: Rotation = "quaternion"  # network.NetworkConfig.rotation
    point_channels: tuple[int, ...] = (64, 128, 1024)  # the per-point MLP (the paper's widths)
    head_channels: tuple[int, ...] = (512, 256)
    validation_fraction: float = 0.1
    val_views: int = 4
    test_views: int = 5
    eval_every: int = 500
    log_every: int = 25
    seed: int = 0
    device: str = "cpu"
    # autocast matmuls to bfloat16, the pose math in fp32; None: where it pays (itnet.cpu.fast_bf16)
    bf16: bool | None = None
    sensor_noise: bool = True  # depth noise, jitter and outliers in the training scans
    scan_mix: list[dict[str, Any]] = [{}, PAPER_VIEWS]  # each training scan: one of these
    # ScanConfig overrides, drawn uniformly ({}: occluded views; PAPER_VIEWS: the paper's rule)
    init_from: Path | None = None  # start from these weights (fine-tuning) instead of scratch
    val_scan: dict[str, Any] = {}  # ScanConfig overrides for the validation scans ({}: occluded)
    # > 1: each training shape stretched along its axes by up to this factor (data.training_batch)
    stretch: float = 1.0
    threads: int = 0  # 0: torch's default
    data_workers: int = 0  # processes making the batches ahead (model/prefetch.py; for a GPU)
    compile: bool = False  # torch.compile the unrolled network for the training steps
    ema: float | None = None  # decay of an exponential moving average of the weights (0.999)
    # not None: an upright model (data.upright_scan): training scans levelled by their up tilted
    # by up to this many degrees; validation runs held upright by an up UPRIGHT_EVAL_DEG off, as
    # the service serves a request that gives up
    upright: float | None = None
    # > 0: this share of the training scans starts within near_deg / near_shift of its answer
    # (data.near_start), the regime of a run's last iterations, where precision is decided
    near_starts: float = Field(0.0, ge=0.0, le=1.0)
    near_deg: float = Field(20.0, gt=0.0)
    near_shift: float = Field(0.2, ge=0.0)


def _save(
    path: Path,
    net: ITNet,
    opt: torch.optim.Optimizer,
    step: int,
    config: TrainConfig,
    metrics: dict,
    ema: AveragedModel | None = None,
) -> None:
    """``net``'s weights as "model" (the network to ship or resume), and for resume the optimiser
    and, when given, the moving average."""
    with written_whole(path) as tmp:
        torch.save(
            {
                "model": net.state_dict(),
                **({"ema": ema.state_dict()} if ema is not None else {}),
                "optimizer": opt.state_dict(),
                "step": step,
                "config": config.model_dump(mode="json"),
                "network": vars(net.config),
                "metrics": metrics,
            },
            tmp,
        )


def training_data(config: TrainConfig) -> CategorySet:
    """A run's training shapes and fixed validation scans (cached: a second call is quick)."""
    return load_category_set(
        config.data,
        category_names(config.category, config.data),
        config.frame,
        config.cache,
        config.check_orientation,
        config.validation_fraction,
        config.seed,
        config.val_views,
        scan_config(config.val_scan),
        config.symmetry,
    )


def train(config: TrainConfig, resume: bool = True, progress: bool = True) -> dict:
    """Train (or resume) a run; returns the best validation metrics."""
    bf16 = prepare_cpu(config.threads, config.bf16, config.device)
    config = config.model_copy(update={"bf16": bf16})
    config.out.mkdir(parents=True, exist_ok=True)
    (config.out / "config.json").write_text(config.model_dump_json(indent=2))
    data = training_data(config)
    quiet = {"depth_noise": (0.0, 0.0), "jitter": (0.0, 0.0), "outlier_fraction": (0.0, 0.0)}
    noise = {} if config.sensor_noise else quiet
    train_scan_configs = [scan_config(noise, overrides) for overrides in config.scan_mix]
    near = None
    if config.near_starts > 0:
        near = NearStarts(config.near_starts, config.near_deg, config.near_shift)

    def make_batch(step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rng = np.random.default_rng([config.seed, step])  # per-step stream: resume-exact data
        picked = data.draw(rng, config.batch)
        x, target = training_batch(
            data.shapes,
            config.batch,
            config.points,
            rng,
            train_scan_configs,
            picked,
            config.stretch,
            config.upright,
            near,
        )
        return x, target, picked

    with Prefetcher(make_batch, config.data_workers) as prefetch:  # forks before CUDA starts
        return _train_loop(config, data, prefetch, resume, progress)


def _train_loop(
    config: TrainConfig, data: CategorySet, prefetch: Prefetcher, resume: bool, progress: bool
) -> dict:
    from tqdm import tqdm

    torch.manual_seed(config.seed)
    net = ITNet(
        NetworkConfig(
            config.point_channels, config.head_channels, config.identity_init, config.rotation
        )
    ).to(config.device)
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    step, best = 0, {"val_accuracy": -1.0}
    last = config.out / "last.pt"
    if resume and last.exists():
        state = torch.load(last, map_location=config.device, weights_only=False)
        net.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        step, best = state["step"], state["metrics"].get("best", best)
    elif config.init_from is not None:
        init = torch.load(config.init_from, map_location=config.device, weights_only=False)
        theirs = network_config(init.get("network", {}))
        shape = ("point_channels", "head_channels", "rotation")
        if can_widen(theirs, net.config):  # a narrower network: the same function, widened
            narrow = ITNet(theirs)
            narrow.load_state_dict(init["model"])
            net.load_state_dict(widen(narrow, net.config, seed=config.seed).state_dict())
        elif any(getattr(theirs, k) != getattr(net.config, k) for k in shape):
            raise ValueError(
                f"--init-from {config.init_from}: its network ({theirs}) is not this run's "
                f"({net.config}); match --rotation and no layer narrower, or start from scratch"
            )
        else:
            net.load_state_dict(init["model"])
    ema = average_of(net, config.ema)
    if ema is not None and resume and last.exists() and "ema" in state:
        ema.load_state_dict(state["ema"])  # a run without it starts its average here
    log = (config.out / "log.jsonl").open("a")
    log.write(
        json.dumps(
            {
                "event": "start",
                "step": step,
                "train_shapes": len(data.shapes),
                "val_scans": {k: len(v.clouds) for k, v in data.validation.items()},
                "symmetry": {k: c.symmetry for k, c in data.categories.items()},
                "orientation": data.orientation,
            }
        )
        + "\n"
    )
    forward = CompiledForward(net, config.compile)
    # a log file (nohup) gets a line a minute, a terminal a live bar
    every_s = 1.0 if sys.stderr.isatty() else 60.0
    bar = tqdm(
        total=config.steps, initial=step, disable=not progress, desc="train", mininterval=every_s
    )
    losses: list[float] = []
    started = time.time()
    for x, target, picked in prefetch.batches(step, config.steps):
        x_t = torch.from_numpy(x).to(config.device)
        target_t = torch.from_numpy(target).to(config.device)
        turns = torch.from_numpy(data.turns[picked]).to(config.device)
        lr = learning_rate(config.lr, config.lr_decay, config.decay_every, step)
        set_schedule(net, opt, lr, bn_momentum(config.bn_momentum, config.bn_decay_every, step))
        net.train()
        with torch.autocast(x_t.device.type, dtype=torch.bfloat16, enabled=config.bf16):
            poses = forward(x_t, config.iterations, stop_gradient=config.stop_gradient)
        loss = torch.stack(
            [
                point_loss(pose.float(), target_t, x_t, turns, config.loss)
                for pose in poses[-config.supervise_last :]
            ]
        ).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if ema is not None:
            ema.update_parameters(net)
        step += 1
        losses.append(float(loss.detach()))
        bar.update(1)
        if step % config.log_every == 0:
            mean = float(np.mean(losses[-config.log_every :]))
            bar.set_postfix(
                loss=f"{mean:.4f}", lr=f"{lr:.1e}", val=f"{best['val_accuracy']:.3f}", refresh=False
            )
            log.write(
                json.dumps(
                    {
                        "step": step,
                        "loss": mean,
                        "lr": lr,
                        "seconds": round(time.time() - started, 1),
                    }
                )
                + "\n"
            )
        if step % config.eval_every == 0 or step == config.steps:
            metrics, chosen = {"step": step, "weights": "raw", **validate(net, data, config)}, net
            if ema is not None:  # the average competes with the raw weights on validation
                averaged = validate(ema.module, data, config)
                metrics["raw_val_accuracy"] = metrics["val_accuracy"]
                metrics["ema_val_accuracy"] = averaged["val_accuracy"]
                metrics["raw_val_median_rotation_deg"] = metrics["val_median_rotation_deg"]
                metrics["ema_val_median_rotation_deg"] = averaged["val_median_rotation_deg"]
                if averaged["val_accuracy"] > metrics["val_accuracy"]:
                    metrics, chosen = {**metrics, **averaged, "weights": "ema"}, ema.module
            if metrics["val_accuracy"] > best["val_accuracy"]:
                best = metrics
                _save(config.out / "best.pt", chosen, opt, step, config, {"best": best, **metrics})
            _save(last, net, opt, step, config, {"best": best, **metrics}, ema)
            log.write(json.dumps({"event": "val", **metrics}) + "\n")
            log.flush()
            if not math.isfinite(float(np.mean(losses[-config.log_every :]))):
                raise FloatingPointError(f"loss is not finite at step {step}")
    bar.close()
    log.close()
    return best


def validate(net: ITNet, data: CategorySet, config: TrainConfig) -> dict:
    """Symmetry-aware accuracy at every iteration on each category's validation scans; the
    selection score ``val_accuracy`` is the mean over categories at the last iteration. Beside
    it, the median rotation error (degrees) and centre error (radii) at the last iteration,
    means over categories: precision, which the accuracy's thresholds hide."""
    curves, rotations, centres = {}, [], []
    for name, scans in data.validation.items():
        ups = None
        if config.upright is not None:  # the same tilts every validation (a fixed stream)
            ups = sensed_ups(
                scans.poses, UPRIGHT_EVAL_DEG, np.random.default_rng([config.seed, 17])
            )
        poses = anytime_poses(
            torch_step(net), scans, config.eval_iterations, config.eval_points, ups=ups
        )
        rep = report(poses, scans, data.categories[name].symmetry)[0]
        curves[name] = rep.accuracy
        rotations.append(rep.median_rotation_deg[-1])
        centres.append(rep.median_translation[-1])
    mean_curve = [round(float(v), 4) for v in np.mean(list(curves.values()), axis=0)]
    per_category = {name: curve[-1] for name, curve in curves.items()}
    return {
        "val_accuracy": mean_curve[-1],
        "val_curve": mean_curve,
        "val_categories": per_category,
        "val_median_rotation_deg": round(float(np.mean(rotations)), 3),
        "val_median_translation": round(float(np.mean(centres)), 4),
    }


def network_config(saved: dict[str, Any]) -> NetworkConfig:
    """A checkpoint's ``network`` entry (lists where tuples were; older ones lack newer fields,
    which take their defaults) -> ``NetworkConfig``."""
    return NetworkConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in saved.items()})


def load_checkpoint(path: Path) -> tuple[ITNet, dict]:
    """A trained network (eval mode, CPU) and its checkpoint dict."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    net = ITNet(network_config(state["network"]))
    net.load_state_dict(state["model"])
    return net.eval(), state


def average_checkpoints(sources: list[Path], target: Path) -> Path:
    """The mean of checkpoints of one network, weights and BatchNorm statistics alike (a "model
    soup", Wortsman et al. 2022): fine-tunes of one start land in one basin, and their mean can
    sit nearer its middle than any of them. Written as the last source's checkpoint (its config
    and metrics; ``averaged_from`` lists the sources), float32, without the optimiser."""
    if len(sources) < 2:
        raise ValueError("average at least two checkpoints")
    states = [torch.load(s, map_location="cpu", weights_only=False) for s in sources]
    networks = {network_config(s["network"]) for s in states}  # frozen dataclasses
    if len(networks) > 1:
        raise ValueError(f"checkpoints of different networks: {', '.join(map(str, networks))}")
    state = {k: v for k, v in states[-1].items() if k not in ("optimizer", "ema")}
    model: dict[str, torch.Tensor] = {}
    for key, last in states[-1]["model"].items():
        if last.is_floating_point():
            model[key] = torch.stack([s["model"][key].float() for s in states]).mean(0)
        else:  # counters (BatchNorm's num_batches_tracked): the last one's
            model[key] = last
    state["model"] = model
    state["averaged_from"] = [str(s) for s in sources]
    target.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, target)
    return target


def ship_checkpoint(source: Path, target: Path, half: bool = False) -> Path:
    """Copy a checkpoint without its optimiser state (a third of the size): what the repo ships.
    ``half``: floating-point weights in float16 (half again; a checkpoint kept to train on from,
    ``--init-from`` reads it back into float32)."""
    state = torch.load(source, map_location="cpu", weights_only=False)
    state.pop("optimizer", None)
    state.pop("ema", None)
    if half:
        state["model"] = {
            k: v.half() if v.is_floating_point() else v for k, v in state["model"].items()
        }
    target.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, target)
    return target
