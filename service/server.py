"""Launch the service under uvicorn: one process, or several workers that each load the models."""

from __future__ import annotations

import os

from fastapi import FastAPI

from itnet.service.app import create_app
from itnet.service.runtime import LoadedModel
from itnet.service.settings import Settings

FACTORY = "itnet.service.server:app_from_env"


def app_from_env() -> FastAPI:
    """The uvicorn factory of worker processes: settings from the ``ITNET_*`` environment."""
    return create_app(Settings())


def settings_to_env(settings: Settings) -> dict[str, str]:
    """``Settings`` -> the ``ITNET_*`` variables that rebuild it (nested: ``__``)."""
    env: dict[str, str] = {}

    def put(prefix: str, values: dict[str, object]) -> None:
        for key, value in values.items():
            name = f"{prefix}{key.upper()}"
            if isinstance(value, dict):
                put(f"{name}__", value)
            elif value is not None:
                env[name] = str(value).lower() if isinstance(value, bool) else str(value)

    put("ITNET_", settings.model_dump(mode="json"))
    return env


def run(
    settings: Settings,
    host: str = "127.0.0.1",
    port: int = 8000,
    workers: int = 1,
    models: dict[str, LoadedModel] | None = None,
    log_level: str = "info",
) -> None:
    """Serve until interrupted. ``models`` (already loaded) are used by a single process; workers
    load their own from ``settings`` passed through the environment."""
    import uvicorn

    # Our own size check answers with an error message first; uvicorn's limit is the backstop.
    ws_max_size = settings.limits.max_ws_message_bytes + 4096
    if workers == 1:
        app = create_app(settings, models)
        uvicorn.run(app, host=host, port=port, log_level=log_level, ws_max_size=ws_max_size)
        return
    os.environ.update(settings_to_env(settings))
    uvicorn.run(
        FACTORY,
        factory=True,
        workers=workers,
        host=host,
        port=port,
        log_level=log_level,
        ws_max_size=ws_max_size,
    )
