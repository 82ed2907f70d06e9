"""``itnet models``: the installed models and what their cards say (the CLI twin of
``GET /v1/models``)."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def models(
    model_dir: Path | None = typer.Option(
        None, help="Folder of .onnx models (default: the ones shipped in the package)."
    ),
    as_json: bool = typer.Option(
        False, "--json", help="Print GET /v1/models's JSON (step_ms measured here)."
    ),
    table: bool = typer.Option(
        False, "--table", help="Print the accuracy table of the cards' measurements (Markdown)."
    ),
) -> None:
    """List the models with category, symmetry, precision, points and measured accuracy."""
    from itnet.model_listing import list_models, listing_lines
    from itnet.pose.runtime import ModelLoadError

    try:
        listing = list_models(model_dir)
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    if as_json:
        typer.echo(json.dumps(listing.reply.model_dump()))
        return
    if table:
        from itnet.accuracy_table import accuracy_table

        typer.echo("\n".join(accuracy_table(listing.reply.models)))
        return
    for line in listing_lines(listing):
        typer.echo(line)
