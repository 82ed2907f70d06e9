"""``itnet centre-fit``: fit a pose model's centre correction and measure it on validation."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from itnet.commands.request_options import REQUEST, request_options
from itnet.model.centre_fit_config import CentreFitOptions


@request_options(CentreFitOptions, into="options")
def centre_fit(
    model: Path = typer.Argument(
        ..., help="An exported pose model (.onnx) of a ModelNet category."
    ),
    options: CentreFitOptions = REQUEST,
) -> None:
    """Fit a model's object-centre correction on its category's training shapes and measure it.

    The scans are posed as served; one run without and with the correction is measured on the
    validation views. ``--write`` stores it in the card, and the service applies it after the
    last step. A second correction that also takes the direction toward the sensor serves
    requests that give ``viewpoint``; with ``--up`` the runs are held upright and the two serve
    requests that give ``up`` (the second, those that give both)."""
    from itnet.model.centre_fit_run import fit_model_centre
    from itnet.model.input_error import InputError
    from itnet.pose.runtime import ModelLoadError

    try:
        done = fit_model_centre(model, options, log=lambda line: typer.echo(line, err=True))
    except (ModelLoadError, InputError) as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    for kind, result in done.results.items():
        typer.echo(f"{kind}: {json.dumps(result)}")
        if kind in done.plain_results:
            plain = json.dumps(done.plain_results[kind])
            typer.echo(f"{kind}, the card's plain correction: {plain}")
        if kind in done.served_viewpoint_results:
            served = json.dumps(done.served_viewpoint_results[kind])
            typer.echo(f"{kind}, the card's viewpoint correction: {served}")
        typer.echo(f"{kind}, with the viewpoint: {json.dumps(done.viewpoint_results[kind])}")
    if done.written is not None:
        typer.echo(f"wrote the correction into {done.written}'s card", err=True)
