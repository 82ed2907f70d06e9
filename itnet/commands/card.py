"""``itnet card MODEL.onnx``: show or change what an exported pose model's card says about its
category, without touching its weights (the card is the graph's metadata)."""

from __future__ import annotations

from pathlib import Path

import typer

from itnet.commands.request_options import REQUEST, request_options
from itnet.export.card_config import CardChanges


@request_options(CardChanges, into="changes")
def card(
    model: Path = typer.Argument(..., help="An exported pose model (.onnx)."),
    changes: CardChanges = REQUEST,
) -> None:
    """Print the card (JSON); with options, write the changed card into the model file."""
    from itnet.export.card_edit import edit_card
    from itnet.model.input_error import InputError
    from itnet.pose.runtime import ModelLoadError

    try:
        done = edit_card(model, changes)
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    except InputError as err:
        raise typer.BadParameter(str(err)) from None
    typer.echo(done.card.model_dump_json(indent=1))
