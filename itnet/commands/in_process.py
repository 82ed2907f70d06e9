"""Models for in-process use (CLI): load once per process, by name, with a clear error."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import typer

from itnet.pose.catalog import Catalog
from itnet.pose.runtime import (
    LoadedClassifier,
    LoadedModel,
    ModelLoadError,
    default_model_dir,
    load_all,
)


@cache
def _loaded(model_dir: Path) -> tuple[dict[str, LoadedModel], LoadedClassifier | None]:
    return load_all(model_dir)


def _models(model_dir: Path) -> dict[str, LoadedModel]:
    return _loaded(model_dir)[0]


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


def get_classifier(model_dir: Path | None = None) -> LoadedClassifier:
    """The category classifier of the folder (default: the shipped one), or a typer error."""
    all_models(model_dir)  # a folder that cannot be loaded says why first
    classifier = _loaded(model_dir or default_model_dir())[1]
    if classifier is None:
        typer.echo(
            f"error: no category classifier in {model_dir or default_model_dir()} "
            "(model 'auto', itnet classify and itnet scene need classifier.onnx)",
            err=True,
        )
        raise typer.Exit(2)
    return classifier


def get_catalog(model_dir: Path | None = None) -> Catalog:
    """Every model of the folder (default: the shipped ones) with its classifier, as the pose
    pipeline serves them, or a typer error (exit 2)."""
    models = all_models(model_dir)
    return Catalog(models, _loaded(model_dir or default_model_dir())[1])
