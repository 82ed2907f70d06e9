"""``itnet train``: train IT-Net for one category from ModelNet10 or any folder of shapes."""

from __future__ import annotations

from pathlib import Path

import typer


def train(
    data: Path = typer.Option(
        Path("../shared/data/modelnet10"),
        help="ModelNet-style root (DATA/CATEGORY/{train,test}) or any folder of meshes/clouds.",
    ),
    category: str = typer.Option(
        "chair",
        help="Category (sub-folder of DATA, if present); a comma list or 'modelnet10' (every "
        "class of DATA) trains one network for several categories.",
    ),
    symmetry: str = typer.Option(
        "auto",
        help="Turns about up under which the category looks alike: none | yaw180 | yaw90 | yaw; "
        "auto: ModelNet10's table (model/categories.py), 'none' for another category. Measure "
        "it with `python -m itnet.model.categories`.",
    ),
    threads: int = typer.Option(0, help="torch threads (0: torch's default)."),
    frame: str = typer.Option("modelnet", help="Frame of the files: modelnet | canonical | z-up."),
    out: Path = typer.Option(Path("runs/chair"), help="Run folder (checkpoints, log, config)."),
    steps: int = typer.Option(9000, help="Optimiser steps."),
    batch: int = typer.Option(32, help="Scans per step."),
    points: int = typer.Option(256, help="Points per training scan."),
    iterations: int = typer.Option(5, help="Unrolled IT-Net iterations."),
    loss: str = typer.Option(
        "squared",
        help="Per-point loss: squared (the paper's ||T x - T* x||²) | distance (||T x - T* x||, "
        "whose gradient does not fade near the target: weighs precision more).",
    ),
    supervise_last: int = typer.Option(
        1, min=1, help="Average the loss over the last M unrolled iterations (the paper: 1)."
    ),
    lr: float = typer.Option(1e-3, help="Initial Adam learning rate."),
    decay_every: int = typer.Option(1125, help="Multiply the learning rate by 0.7 every N steps."),
    eval_every: int = typer.Option(500, help="Validate and checkpoint every N steps."),
    seed: int = typer.Option(0),
    device: str = typer.Option("cpu", help="cpu | cuda"),
    data_workers: int = typer.Option(
        0,
        min=0,
        help="Processes making the scans ahead of each step (on a GPU the scans are "
        "the limit: ~2 per training; 0 makes them in the training process).",
    ),
    bf16: bool | None = typer.Option(
        None,
        "--bf16/--no-bf16",
        help="bfloat16 matmuls, pose math fp32 (default: on a CPU with AMX or AVX-512 BF16 only).",
    ),
    compile: bool = typer.Option(
        True, help="torch.compile the training step (~1.7x on a CPU; eager if it cannot compile)."
    ),
    ema: float = typer.Option(
        0.999,
        help="Keep an exponential moving average of the weights (this decay per step; 0: none); "
        "at each validation the average competes with the raw weights for best.pt.",
    ),
    stop_gradient: bool = typer.Option(
        True, help="Paper: stop the gradient through the moved input."
    ),
    identity_init: bool = typer.Option(True, help="Paper: last layer starts at the identity."),
    rotation: str = typer.Option(
        "quaternion",
        help="What the step regresses: quaternion (the paper's) | 6d (two columns of the "
        "rotation, Gram-Schmidt; continuous).",
    ),
    point_channels: str = typer.Option(
        "64,128,1024", help="Widths of the per-point MLP (the paper's: 64,128,1024)."
    ),
    head_channels: str = typer.Option("512,256", help="Widths of the head (the paper's)."),
    check_orientation: bool = typer.Option(True, help="Fix/drop shapes turned about the up axis."),
    resume: bool = typer.Option(True, help="Continue from OUT/last.pt when it exists."),
    init_from: Path | None = typer.Option(
        None, help="Start from this checkpoint's weights (fine-tuning) instead of from scratch."
    ),
    bn_momentum: float = typer.Option(
        0.5, help="BatchNorm momentum at step 0 (halves every DECAY_EVERY steps, floor 0.01)."
    ),
    val_scanner: str = typer.Option(
        "occluded",
        help="Validation views (model selection): 'occluded', 'paper' or 'surface', or RULE+SENSOR "
        "(occluded+kinect_v2: by that depth camera, at the category's real sizes).",
    ),
    sensors: str = typer.Option(
        "",
        help="Depth cameras to train on too, a comma list of model.sensor presets (kinect_v1, "
        "kinect_v2, realsense_d435): each kind of view also by each camera, at the category's "
        "real sizes; the scans are split evenly.",
    ),
    val_views: int = typer.Option(
        4, min=1, help="Validation views per held-out shape (more for a category of few shapes)."
    ),
    paper_views: bool = typer.Option(
        True, help="Train on the paper's z-buffer views too, half of the scans (view variety)."
    ),
    surface_views: bool = typer.Option(
        False,
        help="Train on surface views too (each point a disc, as a camera sees a mesh; "
        "model/surface.py): the scans are split evenly between the kinds of views.",
    ),
    base_hidden: bool = typer.Option(
        False,
        help="Every training and validation view with the object's base below the view, as a "
        "level camera at head height sees furniture 2-4 m away (model/scanner.py BASE_HIDDEN).",
    ),
    stretch: float = typer.Option(
        1.0,
        min=1.0,
        help="Stretch each training shape along its canonical axes by factors drawn "
        "log-uniformly in [1/S, S] before it is scanned (1: off): more shapes than the "
        "category has; the pose is unchanged.",
    ),
    upright: float | None = typer.Option(
        None,
        metavar="DEG",
        help="An upright model, for requests that give the up direction: every training scan "
        "levelled by its up as a gravity sensor gives it (the truth tilted by up to DEG "
        "degrees), validation runs held upright as the service holds them; its export "
        "requires up.",
    ),
    near_starts: float = typer.Option(
        0.0,
        min=0.0,
        max=1.0,
        metavar="SHARE",
        help="Start this share of the training scans near their answer (within --near-deg "
        "and --near-shift), as a run's last iterations see them: more training where "
        "precision is decided (0: off, the paper's).",
    ),
    near_deg: float = typer.Option(20.0, min=0.1, help="--near-starts: largest angle, degrees."),
    near_shift: float = typer.Option(
        0.2, min=0.0, help="--near-starts: largest shift, in the scan's RMS radii."
    ),
    cache: Path = typer.Option(Path("cache"), help="Cache of canonical shapes and fixed scans."),
) -> None:
    """Train with fresh random partial scans every step; keeps the best validation checkpoint.

    CPU recipe (default): ~60 minutes on 2 cores. Paper recipe on a GPU:
    --device cuda --batch 100 --steps 20000 --decay-every 2000 --data-workers 2 --no-compile
    (35 steps/s on an H200).
    """
    from itnet.model.categories import real_radius_m
    from itnet.model.network import POINT_LOSSES, ROTATIONS
    from itnet.model.scanner import (
        BASE_HIDDEN,
        PAPER_VIEWS,
        SURFACE_VIEWS,
        named_overrides,
        sensor_views,
    )
    from itnet.model.train import TrainConfig
    from itnet.symmetry import SYMMETRY_NAMES

    if symmetry != "auto" and symmetry not in SYMMETRY_NAMES:
        raise typer.BadParameter(f"--symmetry must be auto or one of {', '.join(SYMMETRY_NAMES)}")
    if rotation not in ROTATIONS:
        raise typer.BadParameter(f"--rotation must be one of {', '.join(ROTATIONS)}")
    widths = {"--point-channels": point_channels, "--head-channels": head_channels}
    parsed = {name: _widths(name, text) for name, text in widths.items()}
    if loss not in POINT_LOSSES:
        raise typer.BadParameter(f"--loss must be one of {', '.join(POINT_LOSSES)}")
    try:
        val_scan = named_overrides(val_scanner, category)
        cameras = [
            sensor_views(s.strip(), real_radius_m(category))
            for s in sensors.split(",")
            if s.strip()
        ]
    except ValueError as err:
        raise typer.BadParameter(str(err)) from None
    from itnet.model.train import train as run_training

    views = [{}, *([PAPER_VIEWS] * paper_views), *([SURFACE_VIEWS] * surface_views)]
    views += [{**view, **camera} for camera in cameras for view in views]
    hidden = BASE_HIDDEN if base_hidden else {}

    config = TrainConfig(
        data=data,
        category=category,
        symmetry=None if symmetry == "auto" else symmetry,
        threads=threads,
        frame=frame,
        out=out,
        steps=steps,
        batch=batch,
        points=points,
        iterations=iterations,
        loss=loss,  # type: ignore[arg-type]  # checked against POINT_LOSSES above
        supervise_last=supervise_last,
        lr=lr,
        decay_every=decay_every,
        bn_decay_every=decay_every,
        eval_every=eval_every,
        seed=seed,
        device=device,
        data_workers=data_workers,
        bf16=bf16,
        compile=compile,
        ema=ema or None,
        stop_gradient=stop_gradient,
        identity_init=identity_init,
        rotation=rotation,  # type: ignore[arg-type]  # checked against ROTATIONS above
        point_channels=parsed["--point-channels"],
        head_channels=parsed["--head-channels"],
        check_orientation=check_orientation,
        cache=cache,
        init_from=init_from,
        bn_momentum=(bn_momentum, 0.01),
        scan_mix=[{**rule, **hidden} for rule in views],
        val_scan={**val_scan, **hidden},
        val_views=val_views,
        stretch=stretch,
        upright=upright,
        near_starts=near_starts,
        near_deg=near_deg,
        near_shift=near_shift,
    )
    best = run_training(config, resume=resume)
    typer.echo(
        f"best validation accuracy {best['val_accuracy']:.3f} at step {best.get('step')}; "
        f"checkpoint {out / 'best.pt'}"
    )


def average(
    checkpoints: list[Path] = typer.Argument(..., help="Checkpoints of one network (best.pt ...)."),
    out: Path = typer.Option(..., help="The averaged checkpoint (.pt)."),
) -> None:
    """Average checkpoints of one network (fine-tunes of one start): weights and BatchNorm
    statistics, for `itnet export` or `--init-from` like any checkpoint."""
    from itnet.model.train import average_checkpoints

    try:
        average_checkpoints(checkpoints, out)
    except ValueError as err:
        raise typer.BadParameter(str(err)) from None
    typer.echo(f"wrote {out}: the mean of {len(checkpoints)} checkpoints")


def _widths(option: str, text: str) -> tuple[int, ...]:
    """'64,128,1024' -> (64, 128, 1024); anything but positive integers is refused."""
    try:
        widths = tuple(int(part) for part in text.split(","))
    except ValueError:
        widths = ()
    if not widths or min(widths) < 1:
        raise typer.BadParameter(f"{option} takes positive integers separated by commas: {text!r}")
    return widths
