"""``itnet export``: a trained checkpoint -> one ONNX step graph with its model card."""

from __future__ import annotations

from pathlib import Path

import typer

from itnet.commands.request_options import REQUEST, request_options
from itnet.export.export_config import ExportOptions


@request_options(ExportOptions, into="options")
def export(
    checkpoint: Path = typer.Argument(..., help="Torch checkpoint (best.pt of a run)."),
    options: ExportOptions = REQUEST,
) -> None:
    """Export, then check the graph against torch on random clouds (max abs difference)."""
    from itnet.export.checkpoint_export import export_checkpoint
    from itnet.model.input_error import InputError

    try:
        done = export_checkpoint(checkpoint, options)
    except InputError as err:
        raise typer.BadParameter(str(err)) from None
    typer.echo(
        f"wrote {done.path} ({done.size_bytes / 1e6:.1f} MB); "
        f"ONNX vs torch max |diff| {done.max_diff:.2e}"
    )
