"""``TrainOptions``: every option of a training run as ``itnet train`` offers it (views by name,
cameras as a comma list, switches for the kinds of training views), with the command line's
defaults. ``itnet.model.train_run`` turns them into the run's ``TrainConfig`` and trains.

    report = train_run(TrainOptions(category="bed", out=Path("runs/bed"), steps=6000))

Torch-free, so the command line imports it when it starts; the typer options of ``itnet train``
are derived from its fields (``itnet.commands.request_options``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field


class TrainOptions(BaseModel):
    """What a training run is asked for; the defaults are the CPU recipe."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    data: Path = Field(
        Path("../shared/data/modelnet10"),
        description="ModelNet-style root (DATA/CATEGORY/{train,test}) or any folder of "
        "meshes/clouds",
    )
    category: str = Field(
        "chair",
        description="category (sub-folder of DATA, if present); a comma list or 'modelnet10' "
        "(every class of DATA) trains one network for several categories",
    )
    symmetry: str = Field(
        "auto",
        description="turns about up under which the category looks alike: none | yaw180 | "
        "yaw90 | yaw; auto: ModelNet10's table (model/categories.py), 'none' for another "
        "category. Measure it with `itnet fit categories`",
    )
    threads: int = Field(0, description="torch threads (0: torch's default)")
    frame: str = Field("modelnet", description="frame of the files: modelnet | canonical | z-up")
    out: Path = Field(Path("runs/chair"), description="run folder (checkpoints, log, config)")
    steps: int = Field(9000, description="optimiser steps")
    batch: int = Field(32, description="scans per step")
    points: int = Field(256, description="points per training scan")
    iterations: int = Field(5, description="unrolled IT-Net iterations")
    loss: str = Field(
        "squared",
        description="per-point loss: squared (the paper's ||T x - T* x||²) | distance "
        "(||T x - T* x||, whose gradient does not fade near the target: weighs precision more)",
    )
    supervise_last: int = Field(
        1, ge=1, description="average the loss over the last M unrolled iterations (the paper: 1)"
    )
    lr: float = Field(1e-3, description="initial Adam learning rate")
    decay_every: int = Field(1125, description="multiply the learning rate by 0.7 every N steps")
    eval_every: int = Field(500, description="validate and checkpoint every N steps")
    seed: int = Field(0, description="seed of the split, the initial weights and the scans")
    device: str = Field("cpu", description="torch device: cpu | cuda")
    data_workers: int = Field(
        0,
        ge=0,
        description="processes making the scans ahead of each step (on a GPU the scans are the "
        "limit: ~2 per training; 0 makes them in the training process)",
    )
    bf16: bool | None = Field(
        None,
        description="matmuls in bfloat16, the pose math in fp32 (default: on a CPU with AMX or "
        "AVX-512 BF16 only)",
    )
    compile: bool = Field(
        True,
        description="compile the training step with torch.compile (~1.7x on a CPU; eager if it "
        "cannot compile)",
    )
    ema: float = Field(
        0.999,
        description="keep an exponential moving average of the weights (this decay per step; "
        "0: none); at each validation the average competes with the raw weights for best.pt",
    )
    stop_gradient: bool = Field(
        True, description="paper: stop the gradient through the moved input"
    )
    identity_init: bool = Field(True, description="paper: last layer starts at the identity")
    rotation: str = Field(
        "quaternion",
        description="what the step regresses: quaternion (the paper's) | 6d (two columns of "
        "the rotation, Gram-Schmidt; continuous)",
    )
    point_channels: str = Field(
        "64,128,1024", description="widths of the per-point MLP (the paper's: 64,128,1024)"
    )
    head_channels: str = Field("512,256", description="widths of the head (the paper's)")
    check_orientation: bool = Field(True, description="fix/drop shapes turned about the up axis")
    resume: bool = Field(True, description="continue from OUT/last.pt when it exists")
    init_from: Path | None = Field(
        None,
        description="start from this checkpoint's weights (fine-tuning) instead of from scratch",
    )
    bn_momentum: float = Field(
        0.5,
        description="BatchNorm momentum at step 0 (halves every DECAY_EVERY steps, floor 0.01)",
    )
    val_scanner: str = Field(
        "occluded",
        description="validation views (model selection): 'occluded', 'paper' or 'surface', or "
        "RULE+SENSOR (occluded+kinect_v2: by that depth camera, at the category's real sizes)",
    )
    sensors: str = Field(
        "",
        description="depth cameras to train on too, a comma list of model.sensor presets "
        "(kinect_v1, kinect_v2, realsense_d435): each kind of view also by each camera, at the "
        "category's real sizes; the scans are split evenly",
    )
    val_views: int = Field(
        4,
        ge=1,
        description="validation views per held-out shape (more for a category of few shapes)",
    )
    paper_views: bool = Field(
        True,
        description="train on the paper's z-buffer views too, half of the scans (view variety)",
    )
    surface_views: bool = Field(
        False,
        description="train on surface views too (each point a disc, as a camera sees a mesh; "
        "model/surface.py): the scans are split evenly between the kinds of views",
    )
    base_hidden: bool = Field(
        False,
        description="every training and validation view with the object's base below the "
        "view, as a level camera at head height sees furniture 2-4 m away (model/scanner.py "
        "BASE_HIDDEN)",
    )
    stretch: float = Field(
        1.0,
        ge=1.0,
        description="stretch each training shape along its canonical axes by factors drawn "
        "log-uniformly in [1/S, S] before it is scanned (1: off): more shapes than the category "
        "has; the pose is unchanged",
    )
    upright: float | None = Field(
        None,
        description="an upright model, for requests that give the up direction: every training "
        "scan levelled by its up as a gravity sensor gives it (the truth tilted by up to this "
        "many degrees), validation runs held upright as the service holds them; its export "
        "requires up",
    )
    near_starts: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="start this share of the training scans near their answer (within "
        "--near-deg and --near-shift), as a run's last iterations see them: more training "
        "where precision is decided (0: off, the paper's)",
    )
    near_deg: float = Field(20.0, ge=0.1, description="--near-starts: largest angle, degrees")
    near_shift: float = Field(
        0.2, ge=0.0, description="--near-starts: largest shift, in the scan's RMS radii"
    )
    cache: Path = Field(Path("cache"), description="cache of canonical shapes and fixed scans")
