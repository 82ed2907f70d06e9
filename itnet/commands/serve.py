"""``itnet serve``: the HTTP/WebSocket service under uvicorn (models checked before binding)."""

from __future__ import annotations

from pathlib import Path

import typer


def serve(
    host: str = typer.Option("127.0.0.1", help="Address to bind (0.0.0.0: every interface)."),
    port: int = typer.Option(8000, help="TCP port."),
    workers: int = typer.Option(1, min=1, help="Worker processes; each loads its own models."),
    model_dir: Path | None = typer.Option(
        None, help="Folder of .onnx models (default: ITNET_MODEL_DIR, else the shipped models)."
    ),
    log_level: str = typer.Option("info", help="uvicorn log level."),
) -> None:
    """Serve the estimation API (HTTP and WebSocket) under uvicorn.

    Other settings: ITNET_* environment variables (docs/service.md).

    A missing or corrupt model file: a message and exit code 2, before the port is bound.
    SIGTERM drains: new connections are refused, requests in flight finish (up to
    ITNET_SERVER__GRACEFUL_SHUTDOWN_S), then exit code 0.
    """
    from pydantic import ValidationError

    from itnet.pose.runtime import ModelLoadError, load_models
    from itnet.service.server import run
    from itnet.service.settings import Settings

    try:
        settings = Settings() if model_dir is None else Settings(model_dir=model_dir)
    except ValidationError as err:
        typer.echo(f"error: invalid ITNET_* settings: {err}", err=True)
        raise typer.Exit(2) from None
    try:
        # A single process keeps these; workers reload them, so skip the warm-up here.
        models = load_models(
            settings.model_dir, settings.threads, workers == 1, settings.concurrent_steps
        )
    except (ModelLoadError, ValueError) as err:  # ValueError: an unreadable model card
        typer.echo(f"error: cannot load the models: {err}", err=True)
        raise typer.Exit(2) from None
    wanted = settings.default_model
    if wanted is not None and wanted not in models:
        typer.echo(
            f"error: the default model {wanted!r} is not in {settings.model_dir} "
            f"(found: {', '.join(sorted(models))})",
            err=True,
        )
        raise typer.Exit(2)
    typer.echo(f"itnet: serving {', '.join(sorted(models))} on http://{host}:{port}", err=True)
    run(settings, host, port, workers, models if workers == 1 else None, log_level)
