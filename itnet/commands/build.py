"""``itnet build CATEGORY``: rebuild a category's shipped model, from its data to the files that
ship (``itnet.model.build``: train, evaluate, export, verifier, centre, measure, card, compact),
resumable. Needs the ``train`` extra (torch)."""

from __future__ import annotations

import typer

from itnet.commands.request_options import REQUEST, request_options
from itnet.model.build_config import BuildConfig


@request_options(BuildConfig, into="config", skip=("category",))
def build(
    category: str = typer.Argument(..., help="A category of the registry (ModelNet10)."),
    config: BuildConfig = REQUEST,
) -> None:
    """Fine-tune the category's pose network from earlier weights, measure it, export it with its
    verifier, centre corrections and card, and compact the files. Run it again after a stop: it
    goes on from the first stage not done."""
    from itnet.model.build import build as run_build
    from itnet.model.input_error import InputError

    try:
        report = run_build(
            config.model_copy(update={"category": category}),
            log=lambda line: typer.echo(line, err=True),
        )
    except InputError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    typer.echo(f"{report.model}\n{report.verifier}")
