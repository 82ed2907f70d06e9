"""Training IT-Net: unrolled iterations, PLoss on the final pose, validation, checkpoints, resume.

Run it through ``itnet train``. A run folder holds ``config.json``, ``log.jsonl`` (one line per
logged step, validation lines included), ``last.pt`` (for resume) and ``best.pt`` (best
validation accuracy, the one to ship).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from pydantic import BaseModel

from itnet.model.data import (
    cached_scan_set,
    load_shapes,
    split_files,
    training_batch,
)
from itnet.model.evaluate import anytime_poses, report, torch_step
from itnet.model.network import ITNet, NetworkConfig, point_loss
from itnet.model.scanner import PAPER_VIEWS, scan_config


class TrainConfig(BaseModel):
    """Everything a run depends on; dumped to config.json and stored in every checkpoint."""

    data: Path = Path("../shared/data/modelnet10")
    category: str = "chair"
    frame: str = "modelnet"
    check_orientation: bool = True
    out: Path = Path("runs/chair")
    cache: Path = Path("cache")
    steps: int = 10000
    batch: int = 32
    points: int = 256
    eval_points: int = 1024
    iterations: int = 5
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
    validation_fraction: float = 0.1
    val_views: int = 4
    test_views: int = 5
    eval_every: int = 500
    log_every: int = 25
    seed: int = 0
    device: str = "cpu"
    bf16: bool = True  # autocast matmuls to bfloat16 (AVX-512 BF16 or AMX on CPU), keep the pose math in fp32
    sensor_noise: bool = True  # depth noise, jitter and outliers in the training scans
    scan_mix: list[dict[str, Any]] = [{}, PAPER_VIEWS]  # each training scan: one of these
    # ScanConfig overrides, drawn uniformly ({}: occluded views; PAPER_VIEWS: the paper's rule)
    init_from: Path | None = None  # start from these weights (fine-tuning) instead of scratch
    val_scan: dict[str, Any] = {}  # ScanConfig overrides for the validation scans ({}: occluded)
    threads: int = 0  # 0: torch's default


def _bn_momentum(config: TrainConfig, step: int) -> float:
    start, end = config.bn_momentum
    return max(end, start * 0.5 ** (step / config.bn_decay_every))


def _save(
    path: Path,
    net: ITNet,
    opt: torch.optim.Optimizer,
    step: int,
    config: TrainConfig,
    metrics: dict,
) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(
        {
            "model": net.state_dict(),
            "optimizer": opt.state_dict(),
            "step": step,
            "config": config.model_dump(mode="json"),
            "network": vars(net.config),
            "metrics": metrics,
        },
        tmp,
    )
    tmp.replace(path)


def train(config: TrainConfig, resume: bool = True, progress: bool = True) -> dict:
    """Train (or resume) a run; returns the best validation metrics."""
    from tqdm import tqdm

    if config.threads:
        torch.set_num_threads(config.threads)
    config.out.mkdir(parents=True, exist_ok=True)
    (config.out / "config.json").write_text(config.model_dump_json(indent=2))
    files = split_files(config.data, config.category, config.validation_fraction, config.seed)
    train_shapes, orient = load_shapes(
        files["train"], config.frame, config.cache, config.check_orientation
    )
    val_shapes, _ = load_shapes(files["val"], config.frame, config.cache, config.check_orientation)
    quiet = {"depth_noise": (0.0, 0.0), "jitter": (0.0, 0.0), "outlier_fraction": (0.0, 0.0)}
    noise = {} if config.sensor_noise else quiet
    train_scan_configs = [scan_config(noise, overrides) for overrides in config.scan_mix]
    val_scans = cached_scan_set(
        val_shapes, config.val_views, config.seed + 7, scan_config(config.val_scan), config.cache
    )

    torch.manual_seed(config.seed)
    net = ITNet(NetworkConfig(identity_init=config.identity_init)).to(config.device)
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    step, best = 0, {"val_accuracy": -1.0}
    last = config.out / "last.pt"
    if resume and last.exists():
        state = torch.load(last, map_location=config.device, weights_only=False)
        net.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        step, best = state["step"], state["metrics"].get("best", best)
    elif config.init_from is not None:
        net.load_state_dict(torch.load(config.init_from, map_location=config.device)["model"])
    log = (config.out / "log.jsonl").open("a")
    log.write(
        json.dumps(
            {
                "event": "start",
                "step": step,
                "train_shapes": len(train_shapes),
                "val_scans": len(val_scans.clouds),
                "orientation": orient,
            }
        )
        + "\n"
    )
    bar = tqdm(total=config.steps, initial=step, disable=not progress, desc="train")
    losses: list[float] = []
    started = time.time()
    while step < config.steps:
        rng = np.random.default_rng([config.seed, step])  # per-step stream: resume-exact data
        x, target = training_batch(
            train_shapes, config.batch, config.points, rng, train_scan_configs
        )
        x_t = torch.from_numpy(x).to(config.device)
        target_t = torch.from_numpy(target).to(config.device)
        lr = config.lr * config.lr_decay ** (step / config.decay_every)
        for group in opt.param_groups:
            group["lr"] = lr
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                module.momentum = _bn_momentum(config, step)
        net.train()
        with torch.autocast(x_t.device.type, dtype=torch.bfloat16, enabled=config.bf16):
            poses = net(x_t, config.iterations, stop_gradient=config.stop_gradient)
        loss = point_loss(poses[-1].float(), target_t, x_t)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        losses.append(float(loss.detach()))
        bar.update(1)
        if step % config.log_every == 0:
            mean = float(np.mean(losses[-config.log_every :]))
            bar.set_postfix(loss=f"{mean:.4f}", lr=f"{lr:.1e}", val=f"{best['val_accuracy']:.3f}")
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
            poses_val = anytime_poses(
                torch_step(net), val_scans, config.eval_iterations, config.eval_points
            )
            rep, _, _ = report(poses_val, val_scans)
            metrics = {"step": step, "val_accuracy": rep.accuracy[-1], "val_curve": rep.accuracy}
            if metrics["val_accuracy"] > best["val_accuracy"]:
                best = metrics
                _save(config.out / "best.pt", net, opt, step, config, {"best": best, **metrics})
            _save(last, net, opt, step, config, {"best": best, **metrics})
            log.write(json.dumps({"event": "val", **metrics}) + "\n")
            log.flush()
            if not math.isfinite(float(np.mean(losses[-config.log_every :]))):
                raise FloatingPointError(f"loss is not finite at step {step}")
    bar.close()
    log.close()
    return best


def load_checkpoint(path: Path) -> tuple[ITNet, dict]:
    """A trained network (eval mode, CPU) and its checkpoint dict."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    net = ITNet(
        NetworkConfig(
            **{k: tuple(v) if isinstance(v, list) else v for k, v in state["network"].items()}
        )
    )
    net.load_state_dict(state["model"])
    return net.eval(), state


def ship_checkpoint(source: Path, target: Path) -> Path:
    """Copy a checkpoint without its optimiser state (a third of the size): what the repo ships."""
    state = torch.load(source, map_location="cpu", weights_only=False)
    state.pop("optimizer", None)
    target.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, target)
    return target
