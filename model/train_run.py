"""A training run from ``TrainOptions``: the options checked and turned into the run's
``TrainConfig`` (the kinds of training views, the validation views, the network's widths),
then ``itnet.model.train.train``.

    report = train_run(TrainOptions(data=Path("shapes"), category="mug", frame="canonical"))
    report.val_accuracy, report.checkpoint      # 0.62, runs/chair/best.pt
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from itnet.model.categories import real_radius_m
from itnet.model.input_error import InputError
from itnet.model.network import POINT_LOSSES, ROTATIONS
from itnet.model.scanner import (
    BASE_HIDDEN,
    PAPER_VIEWS,
    SURFACE_VIEWS,
    named_overrides,
    sensor_views,
)
from itnet.model.train import TrainConfig, train
from itnet.model.train_config import TrainOptions
from itnet.symmetry import SYMMETRY_NAMES

AS_GIVEN = (
    "data", "category", "threads", "frame", "out", "steps", "batch", "points", "iterations",
    "loss", "supervise_last", "lr", "decay_every", "eval_every", "seed", "device", "data_workers",
    "bf16", "compile", "stop_gradient", "identity_init", "rotation", "check_orientation", "cache",
    "init_from", "val_views", "stretch", "upright", "near_starts", "near_deg", "near_shift",
)  # fmt: skip
"""The options a ``TrainConfig`` takes as they are, under the same name."""


@dataclass(frozen=True)
class TrainReport:
    """The best validation of a run: its accuracy, the step it was reached at, the checkpoint
    that holds it, and every metric of that validation."""

    val_accuracy: float
    step: int | None
    checkpoint: Path
    metrics: dict[str, Any] = field(default_factory=dict)


def train_run(options: TrainOptions, progress: bool = True) -> TrainReport:
    """Train (or resume, with ``options.resume``) the run ``options`` ask for. Raises
    InputError before anything is written where an option is refused."""
    config = train_config(options)
    best = train(config, resume=options.resume, progress=progress)
    return TrainReport(
        val_accuracy=float(best["val_accuracy"]),
        step=best.get("step"),
        checkpoint=config.out / "best.pt",
        metrics=dict(best),
    )


def train_config(options: TrainOptions) -> TrainConfig:
    """The run's ``TrainConfig`` of ``options``: 'auto' symmetry as the table's, the widths as
    tuples, the EMA decay 0 as none, the view switches and cameras as the mix of training
    views. Raises InputError for an unknown choice, bad widths, view rule or camera."""
    if options.symmetry != "auto" and options.symmetry not in SYMMETRY_NAMES:
        raise InputError(f"--symmetry must be auto or one of {', '.join(SYMMETRY_NAMES)}")
    if options.rotation not in ROTATIONS:
        raise InputError(f"--rotation must be one of {', '.join(ROTATIONS)}")
    point_channels = widths("--point-channels", options.point_channels)
    head_channels = widths("--head-channels", options.head_channels)
    if options.loss not in POINT_LOSSES:
        raise InputError(f"--loss must be one of {', '.join(POINT_LOSSES)}")
    scan_mix, val_scan = training_views(options)
    return TrainConfig(
        **{name: getattr(options, name) for name in AS_GIVEN},
        symmetry=None if options.symmetry == "auto" else options.symmetry,
        bn_decay_every=options.decay_every,
        ema=options.ema or None,
        point_channels=point_channels,
        head_channels=head_channels,
        bn_momentum=(options.bn_momentum, 0.01),
        scan_mix=scan_mix,
        val_scan=val_scan,
    )


def training_views(options: TrainOptions) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """(the ScanConfig overrides each training scan draws one of, the validation scans'):
    occluded views, the paper's and surface views where switched on, each also by every camera
    of ``options.sensors``; the base hidden in all where asked. Raises InputError for an
    unknown view rule or camera."""
    try:
        val_scan = named_overrides(options.val_scanner, options.category)
        radius = real_radius_m(options.category)
        cameras = [sensor_views(s.strip(), radius) for s in options.sensors.split(",") if s.strip()]
    except ValueError as err:
        raise InputError(str(err)) from None
    views: list[dict[str, Any]] = [{}]
    views += [PAPER_VIEWS] * options.paper_views + [SURFACE_VIEWS] * options.surface_views
    views += [{**view, **camera} for camera in cameras for view in views]
    hidden = BASE_HIDDEN if options.base_hidden else {}
    return [{**rule, **hidden} for rule in views], {**val_scan, **hidden}


def widths(option: str, text: str) -> tuple[int, ...]:
    """'64,128,1024' -> (64, 128, 1024); anything but positive integers is refused
    (InputError naming ``option``)."""
    try:
        parsed = tuple(int(part) for part in text.split(","))
    except ValueError:
        parsed = ()
    if not parsed or min(parsed) < 1:
        raise InputError(f"{option} takes positive integers separated by commas: {text!r}")
    return parsed
