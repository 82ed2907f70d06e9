"""Launch the service under uvicorn: one process, or several workers that each load the models.

The connection-level limits (``Settings.server``) become uvicorn's options, see
:func:`uvicorn_options`. SIGTERM drains: uvicorn stops accepting connections, lets the requests in
flight finish (up to ``graceful_shutdown_s``), and the process then exits with status 0.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import TYPE_CHECKING, Any

from fastapi import FastAPI

from itnet.pose.runtime import LoadedModel
from itnet.pose.shared_work import SHARED_ADMISSION_ENV
from itnet.service.app import create_app
from itnet.service.guards.protocol import GuardedHttpToolsProtocol
from itnet.service.guards.ws_protocol import GuardedWebSocketProtocol
from itnet.service.metrics import MULTIPROCESS_DIR_ENV, multiprocess_dir
from itnet.service.settings import ServerSettings, Settings

if TYPE_CHECKING:
    import uvicorn

FACTORY = "itnet.service.server:app_from_env"
log = logging.getLogger("itnet.service")


def app_from_env() -> FastAPI:
    """The uvicorn factory of worker processes: settings from the ``ITNET_*`` environment."""
    settings = Settings()
    GuardedHttpToolsProtocol.configure(settings.server, settings.limits.retry_after_s)
    return create_app(settings)


@contextmanager
def serving_in_thread(
    app: FastAPI, settings: Settings, start_s: float = 10.0
) -> Iterator[tuple[str, uvicorn.Server]]:
    """``app`` served by uvicorn with ``settings``' limits on a free loopback port, in a thread
    of this process (tests, benchmarks) -> (its URL, the server); stopped, and the protocol's
    limits set back to the defaults, on exit. RuntimeError where it does not start within
    ``start_s``."""
    import uvicorn

    GuardedHttpToolsProtocol.configure(settings.server, settings.limits.retry_after_s)
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    config = uvicorn.Config(app, log_level="warning", **uvicorn_options(settings))
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + start_s
        while not server.started:
            if not thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the server did not start")
            time.sleep(0.01)
        yield f"http://127.0.0.1:{sock.getsockname()[1]}", server
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        sock.close()
        GuardedHttpToolsProtocol.configure(ServerSettings())


def uvicorn_options(settings: Settings) -> dict[str, Any]:
    """``Settings`` -> keyword arguments of ``uvicorn.run``: every connection-level limit."""
    server, limits = settings.server, settings.limits
    return {
        # The connection table, the head's deadline and size cap (protocol.py), the WebSocket
        # message budget (ws_protocol.py).
        "http": GuardedHttpToolsProtocol,
        "ws": GuardedWebSocketProtocol,
        # Our own size check answers with an error message first; uvicorn's is the backstop.
        "ws_max_size": limits.max_ws_message_bytes + 4096,
        "ws_max_queue": server.ws_max_queue,
        "ws_ping_interval": server.ws_ping_interval_s,
        "ws_ping_timeout": server.ws_ping_timeout_s,
        # Not uvicorn's limit_concurrency: the connection table counts WebSockets too, lets a
        # newcomer evict an idle connection, and keeps a lane for probes (connections.py).
        "limit_concurrency": None,
        "backlog": server.backlog,
        "timeout_keep_alive": server.keep_alive_s,
        "timeout_graceful_shutdown": server.graceful_shutdown_s,
    }


def _exit_after_drain(signum: int, frame: FrameType | None) -> None:
    """SIGTERM outside uvicorn's own handler: before serving, or re-raised by uvicorn once it
    has drained. Either way the stop was asked for: exit 0."""
    log.info("stopped by signal %d", signum)
    raise SystemExit(0)


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

    options = uvicorn_options(settings)
    if workers == 1:
        GuardedHttpToolsProtocol.configure(settings.server, settings.limits.retry_after_s)
        app = create_app(settings, models)
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, _exit_after_drain)
        uvicorn.run(app, host=host, port=port, log_level=log_level, **options)
        return
    os.environ.update(settings_to_env(settings))
    # The workers' metrics add up in one folder (service/metrics.py), unless the operator named
    # one; a folder made here is removed when the server stops.
    made = None if multiprocess_dir() else tempfile.mkdtemp(prefix="itnet-metrics-")
    if made is not None:
        os.environ[MULTIPROCESS_DIR_ENV] = made
    # ... and they admit one machine's worth of estimates together (itnet/pose/shared_work.py)
    shared = tempfile.mkdtemp(prefix="itnet-admission-")
    os.environ[SHARED_ADMISSION_ENV] = os.path.join(shared, "admitted")
    try:
        uvicorn.run(
            FACTORY, factory=True, workers=workers, host=host, port=port, log_level=log_level,
            **options,
        )  # fmt: skip
    finally:
        os.environ.pop(SHARED_ADMISSION_ENV, None)
        shutil.rmtree(shared, ignore_errors=True)
        if made is not None:
            os.environ.pop(MULTIPROCESS_DIR_ENV, None)
            shutil.rmtree(made, ignore_errors=True)
