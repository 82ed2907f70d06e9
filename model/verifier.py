"""A learned verifier: which of a pose model's fused runs on a cloud put it right.

Of the views that K fused runs miss, about half have a right run among the K (docs/ensemble.md):
the fusion follows the majority, and a wrong basin can hold it. The verifier is a PointNet
(``PointNetHead``, one output) that looks at a run's points where the run's pose puts them, in
the canonical frame (``itnet.basin.canonical_points``), and gives the logit of the pose being
right: a chair put upside down or turned a quarter about up looks wrong there, whatever the
network's regression made of it. The engine's ``verify`` anchors the fusion on the run it finds
likeliest (``itnet.basin.likeliest_run``).

Training data (``pose_runs``): the pose model's own runs, K from turned starts each on its own
subset as the engine runs them (``itnet.model.evaluate.run_poses``), on fixed scans of the
category's training shapes (never its validation shapes), each labelled by its rotation error
(symmetry-aware): right below ``right_deg``, wrong above ``wrong_deg``, the band between left out.
A ``synthetic`` share of every batch is instead the truth knocked off: by a few degrees (right),
by one of the cube's 23 turns and a few degrees (the network's usual wrong basins: quarter and
half turns), or by any rotation (wrong).

    itnet verifier-train --pose-model itnet/models/chair.onnx --out runs/verifier/chair
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from numpy.typing import NDArray
from pydantic import BaseModel, Field, field_validator

from itnet.basin import canonical_points
from itnet.geometry import axis_angle_to_matrix, random_rotation, viewing_axis_turns
from itnet.model.classify.network import PointNetHead
from itnet.preprocess import pose_to_normalized, resample
from itnet.symmetry import symmetric_rotation_error_deg
from itnet.upright import sensed_ups, upright_starts

if TYPE_CHECKING:
    from itnet.model.data import ScanSet
    from itnet.pose.runtime import LoadedModel


class VerifierConfig(BaseModel):
    """How a verifier is trained (stored beside its weights)."""

    category: str = "chair"
    pose_model: Path = Field(description="the exported pose model whose runs it learns from")
    views: int = Field(8, ge=1, description="scans of each training shape, per view rule")
    scanners: list[str] = Field(
        ["paper", "occluded", "surface"],
        description="view rules: RULE, RULE+SENSOR (by a depth camera, at the category's real "
        "sizes), RULE+SENSOR+crop (cut out of a room) or RULE+SENSOR+clutter (things on it)",
    )
    ensemble: int = Field(8, ge=1, description="runs per scan, from turned starts")
    points: int = Field(256, ge=16, description="points of a run the verifier sees")
    steps: int = Field(4000, ge=1)
    batch: int = Field(128, ge=2)
    lr: float = Field(1e-3, gt=0)
    synthetic: float = Field(0.5, ge=0, le=1, description="share of knocked-off truths a batch")
    up_error_deg: float | None = Field(
        None, ge=0, le=45,
        description="runs held upright, each scan's up given this far off the truth (default: "
        "2 where the pose model requires up, else the runs are free)",
    )  # fmt: skip
    right_deg: float = 15.0
    wrong_deg: float = 25.0
    point_channels: tuple[int, ...] = (64, 128, 512)
    head_channels: tuple[int, ...] = (256,)
    seed: int = 0
    threads: int = 2
    data: Path = Path("../shared/data/modelnet10")
    cache: Path = Path("cache")

    @field_validator("scanners")
    @classmethod
    def _known_views(cls, scanners: list[str]) -> list[str]:
        from itnet.model.scanner import view_name_parts

        for name in scanners:
            view_name_parts(name)  # ValueError: an unknown rule or camera
        return scanners


UPRIGHT_UP_ERROR_DEG = 2.0
"""How far off the truth the up is that the runs of a model requiring up are held upright on."""


@dataclass
class PoseRuns:
    """K runs of a pose model on S scans: points (S, K, P, 3) and poses (S, K, 4, 4) in each
    scan's normalised frame, rotation errors (S, K) in degrees, truths (S, 4, 4) in the same
    frame."""

    points: NDArray[np.float16]
    poses: NDArray[np.float32]
    errors: NDArray[np.float32]
    truths: NDArray[np.float32]

    @classmethod
    def concatenate(cls, parts: list[PoseRuns]) -> PoseRuns:
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in _FIELDS))


_FIELDS = ("points", "poses", "errors", "truths")


def pose_runs(
    model: LoadedModel,
    scans: ScanSet,
    ensemble: int,
    points: int,
    seed: int = 0,
    up_error_deg: float | None = None,
) -> PoseRuns:
    """A LoadedModel's runs on a ScanSet as the engine fuses them (``ensemble`` turned starts,
    each on its own subset), every run's points resampled to ``points``. ``up_error_deg``: the
    runs start stood up and are held upright, each scan's up given this far off the truth."""
    from itnet.model.evaluate import run_poses

    starts = viewing_axis_turns(ensemble) if ensemble > 1 else None
    symmetry = model.card.symmetry
    out: dict[str, list] = {f: [] for f in _FIELDS}
    for i, cloud in enumerate(scans.clouds):
        rng = np.random.default_rng(seed + i)
        up = None
        if up_error_deg is not None:
            up = sensed_ups(scans.poses[i][None], up_error_deg, rng)[0]
            starts = upright_starts(up, ensemble)
        poses, x, norm = run_poses(model, cloud, starts, seed + i, up=up)
        truth = pose_to_normalized(scans.poses[i], norm)
        out["points"].append(np.stack([resample(run, points, rng) for run in x]))
        out["poses"].append(poses)
        out["errors"].append(
            symmetric_rotation_error_deg(poses[:, :3, :3], truth[None, :3, :3], symmetry)
        )
        out["truths"].append(truth)
    return PoseRuns(
        np.asarray(out["points"], np.float16),
        np.asarray(out["poses"], np.float32),
        np.asarray(out["errors"], np.float32),
        np.asarray(out["truths"], np.float32),
    )


def training_runs(
    model: LoadedModel, config: VerifierConfig, log: Callable[[str], None] = print
) -> PoseRuns:
    """A LoadedModel's (``config.pose_model``) runs on the category's training scans of every
    view rule (cached under ``config.cache``, keyed by the model file's bytes and the settings
    that shape them)."""
    from itnet.model.categories import category
    from itnet.model.category_set import training_scans
    from itnet.model.scanner import named_views

    cat = category(config.category, model.card.symmetry)
    digest = hashlib.sha256(config.pose_model.read_bytes()).hexdigest()[:12]
    up_error = runs_up_error(model, config)
    parts = []
    for index, scanner in enumerate(config.scanners):
        key = f"{digest}-{config.category}-{scanner}-{config.views}-{config.ensemble}"
        if up_error is not None:
            key += f"-up{up_error:g}"
        path = config.cache / f"verifier-runs-{key}-{config.points}-{config.seed}.npz"
        if path.exists():
            z = np.load(path)
            parts.append(PoseRuns(*(z[f] for f in _FIELDS)))
            continue
        started = time.perf_counter()
        scans = training_scans(
            config.data, cat, views=config.views, seed=config.seed + 101 + index,
            scan=named_views(scanner, config.category), cache=config.cache,
        )  # fmt: skip
        runs = pose_runs(model, scans, config.ensemble, config.points, config.seed, up_error)
        config.cache.mkdir(parents=True, exist_ok=True)
        np.savez(path, **{f: getattr(runs, f) for f in _FIELDS})
        wrong = float((runs.errors > config.wrong_deg).mean())
        log(f"{scanner}: {len(scans.clouds)} scans, {wrong:.1%} of runs wrong "
            f"({time.perf_counter() - started:.0f} s)")  # fmt: skip
        parts.append(runs)
    return PoseRuns.concatenate(parts)


def runs_up_error(model: LoadedModel, config: VerifierConfig) -> float | None:
    """The up error the training runs are held upright with: the config's, else 2 degrees where
    the pose model requires up, else None (free runs)."""
    if config.up_error_deg is not None:
        return config.up_error_deg
    return UPRIGHT_UP_ERROR_DEG if model.card.requires_up else None


def cube_turns() -> NDArray[np.float64]:
    """The cube's 24 rotations (24, 3, 3), the identity first."""
    turns = []
    for a in np.eye(3):
        for b in np.eye(3):
            for sa in (1, -1):
                for sb in (1, -1):
                    if abs(a @ b) < 0.5:
                        turns.append(np.stack([sa * a, sb * b, np.cross(sa * a, sb * b)]))
    turns.sort(key=lambda r: -np.trace(r))
    return np.array(turns)


def _small_turns(rng: np.random.Generator, count: int, max_deg: float) -> NDArray[np.float64]:
    axes = rng.normal(size=(count, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axis_angle_to_matrix(axes, np.radians(rng.uniform(0, max_deg, count)))


def _yaws(rng: np.random.Generator, angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Turns about the canonical up by ``angles`` (radians), each tilted up to 3 degrees."""
    turns = axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), angles)
    return turns @ _small_turns(rng, len(angles), 3.0)


def hypothesis_batch(
    runs: PoseRuns,
    config: VerifierConfig,
    symmetry: str,
    rng: np.random.Generator,
    upright: bool = False,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """One batch -> (points where each hypothesis puts them (B, P, 3), labels (B,) 1 right /
    0 wrong, weights (B,) 0 for the band between right and wrong). ``upright``: the knocked-off
    truths stay upright (turned about up: a few degrees, a quarter or half turn, or any yaw), as
    runs held upright can only be wrong."""
    s = rng.integers(len(runs.errors), size=config.batch)
    k = rng.integers(runs.errors.shape[1], size=config.batch)
    points = runs.points[s, k].astype(np.float32)
    poses = runs.poses[s, k].astype(np.float64)
    errors = runs.errors[s, k].astype(np.float64)
    knocked = rng.random(config.batch) < config.synthetic
    if knocked.any():
        truths = runs.truths[s[knocked]].astype(np.float64)
        n = len(truths)
        kind = rng.random(n)
        turns = _small_turns(rng, n, 10.0)  # right: a few degrees off
        cube = (kind >= 0.4) & (kind < 0.8)  # one of the cube's turns, a few degrees off
        turns[cube] = cube_turns()[rng.integers(1, 24, int(cube.sum()))] @ _small_turns(
            rng, int(cube.sum()), 12.0
        )
        anywhere = kind >= 0.8
        turns[anywhere] = random_rotation(rng, int(anywhere.sum()))
        if upright:
            near, quarter = kind < 0.4, np.radians(90.0) * rng.integers(1, 4, n)
            angles = np.where(near, 0.0, np.where(cube, quarter, rng.uniform(0, 2 * np.pi, n)))
            angles += np.radians(rng.uniform(-10.0, 10.0, n))
            turns = _yaws(rng, angles)
        hypotheses = truths.copy()
        hypotheses[:, :3, :3] = turns @ truths[:, :3, :3]
        hypotheses[:, :3, 3] = np.einsum("nij,nj->ni", turns, truths[:, :3, 3])
        hypotheses[:, :3, 3] += rng.normal(0.0, 0.05, (n, 3))
        poses[knocked] = hypotheses
        errors[knocked] = symmetric_rotation_error_deg(
            hypotheses[:, :3, :3], truths[:, :3, :3], symmetry
        )
    right, wrong = errors < config.right_deg, errors > config.wrong_deg
    x = canonical_points(points, poses)
    return x, right.astype(np.float32), (right | wrong).astype(np.float32)


def make_verifier(config: VerifierConfig) -> PointNetHead:
    return PointNetHead(1, config.point_channels, config.head_channels)


def train_verifier(config: VerifierConfig, out: Path, log: Callable[[str], None] = print) -> Path:
    """Train on the pose model's runs; writes ``out/verifier.pt`` (weights and config) every
    500 steps and at the end, ``out/log.jsonl``. Returns the checkpoint's path."""
    from itnet.model.categories import category
    from itnet.pose.runtime import load_model

    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(config.model_dump_json(indent=1))
    model = load_model(config.pose_model, threads=config.threads, warm_up=False)
    symmetry = model.card.symmetry
    category(config.category, symmetry)  # an unknown category fails before the runs
    runs = training_runs(model, config, log)
    upright = runs_up_error(model, config) is not None
    net = make_verifier(config)
    optimiser = torch.optim.Adam(net.parameters(), config.lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, config.steps)
    rng = np.random.default_rng(config.seed)
    path, started = out / "verifier.pt", time.perf_counter()
    with (out / "log.jsonl").open("w") as log_file:
        for step in range(1, config.steps + 1):
            batch = hypothesis_batch(runs, config, symmetry, rng, upright)
            x, y, w = (torch.from_numpy(a) for a in batch)
            logits = net(x)[:, 0]
            loss = torch.nn.functional.binary_cross_entropy_with_logits(
                logits, y, weight=w, reduction="sum"
            ) / w.sum().clamp(min=1.0)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            if step % 100 == 0 or step == config.steps:
                hit = float((((logits > 0).float() == y).float() * w).sum() / w.sum().clamp(min=1))
                row = {"step": step, "loss": round(loss.item(), 4), "accuracy": round(hit, 4),
                       "seconds": round(time.perf_counter() - started, 1)}  # fmt: skip
                log_file.write(json.dumps(row) + "\n")
                log_file.flush()
            if step % 500 == 0 or step == config.steps:
                torch.save({"config": config.model_dump(mode="json"), "state": net.state_dict(),
                            "step": step}, path)  # fmt: skip
                log(f"step {step}: loss {loss.item():.4f}")
    return path


def load_verifier(path: Path) -> tuple[PointNetHead, VerifierConfig]:
    """A checkpoint of ``train_verifier`` -> (the network in eval mode, its config)."""
    saved = torch.load(path, map_location="cpu", weights_only=False)
    config = VerifierConfig.model_validate(saved["config"])
    net = make_verifier(config)
    net.load_state_dict(saved["state"])
    return net.eval(), config
