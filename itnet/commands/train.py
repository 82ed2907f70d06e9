"""``itnet train``: train IT-Net for one category from ModelNet10 or any folder of shapes."""

from __future__ import annotations

from pathlib import Path

import typer

from itnet.commands.request_options import REQUEST, request_options
from itnet.model.train_config import TrainOptions


@request_options(TrainOptions, into="options")
def train(options: TrainOptions = REQUEST) -> None:
    """Train with fresh random partial scans every step; keeps the best validation checkpoint.

    CPU recipe (default): ~60 minutes on 2 cores. Paper recipe on a GPU:
    --device cuda --batch 100 --steps 20000 --decay-every 2000 --data-workers 2 --no-compile
    (35 steps/s on an H200).
    """
    from itnet.model.input_error import InputError
    from itnet.model.train_run import train_run

    try:
        report = train_run(options)
    except InputError as err:
        raise typer.BadParameter(str(err)) from None
    typer.echo(
        f"best validation accuracy {report.val_accuracy:.3f} at step {report.step}; "
        f"checkpoint {report.checkpoint}"
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
