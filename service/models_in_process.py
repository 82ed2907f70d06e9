"""Models for in-process use (CLI): load once per process, by name, with a clear error."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import typer

from itnet.service.runtime import LoadedModel, ModelLoadError, default_model_dir, load_models


@cache
def _models(model_dir: Path) -> dict[str, LoadedModel]:
    return load_models(model_dir)


def all_models(model_dir: Path | None = None) -> dict[str, LoadedModel]:
    """Every model of the folder (default: the shipped ones) by name, or a typer error (exit 2)."""
    try:
        return _models(model_dir or default_model_dir())
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None


def get_model(name: str, model_dir: Path | None = None) -> LoadedModel:
    """The named model, or a typer error (exit 2) listing what is available."""
    models = all_models(model_dir)
    if name not in models:
        typer.echo(
            f"error: unknown model {name!r} (available: {', '.join(sorted(models))})", err=True
        )
        raise typer.Exit(2)
    return models[name]
