"""``itnet compact MODEL.onnx...``: store a model file's large weights as float16 (computed in
float32), as the shipped models are. Needs the ``train`` extra (onnx)."""

from __future__ import annotations

from pathlib import Path

import typer


def compact(
    models: list[Path] = typer.Argument(..., help="ONNX model files, rewritten in place."),
) -> None:
    """Halve each model file: its float32 weights of 1,024 values or more stored as float16 and
    cast back to float32 when loaded (each weight moves by at most a relative 2**-11). A file
    already compacted is left as it is."""
    from itnet.export.half_storage import store_half

    for path in models:
        if not path.is_file():
            typer.echo(f"error: {path}: no such file", err=True)
            raise typer.Exit(2)
        saved = store_half(path)
        typer.echo(f"{path}: {saved / 1e6:.2f} MB smaller, now {path.stat().st_size / 1e6:.2f} MB")
