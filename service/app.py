"""The FastAPI app: wiring only (state, routes, error handlers, metrics middleware)."""

from __future__ import annotations

import logging
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import anyio
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from itnet import __version__
from itnet.alignment.warm_up import warm_up as warm_up_alignment
from itnet.pose.runtime import LoadedModel
from itnet.scene.warm_up import warm_up as warm_up_scenes
from itnet.service.api.routes import align, estimate, examples, page, scene, stream, system
from itnet.service.errors import ServiceError, describe_errors
from itnet.service.gc_tuning import GcPauseRecorder, freeze_startup_objects
from itnet.service.metrics import Metrics, RequestMetricsMiddleware
from itnet.service.settings import Settings
from itnet.service.state import ServiceState

log = logging.getLogger("itnet.service")
THREADS_BESIDES = 8  # worker threads beyond one per admitted estimate (other endpoints' work)

DESCRIPTION = """Anytime pose estimation of partial point clouds with IT-Net.

Send a cloud of an object of a known category; get `T_canonical_from_input` (4x4, row-major,
translation in the input's units), refined one iteration at a time within `budget_ms`.
`POST /v1/estimate` answers once; `WS /v1/estimate/stream` sends every iteration as it exists.
"""


def create_app(
    settings: Settings | None = None, models: dict[str, LoadedModel] | None = None
) -> FastAPI:
    """The service. Models load at start-up (lifespan) from ``settings.model_dir`` unless
    ``models`` are given; if none load, the app still answers /healthz and /readyz says why."""
    settings = settings or Settings()
    metrics = Metrics()
    state = ServiceState(settings, metrics, models=dict(models or {}))

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        state.load()
        log.info("models loaded: %s", ", ".join(state.models) or "none")
        if settings.warm_up and state.ready and state.catalog.classifier is not None:
            try:  # the first POST /v1/scene then costs what every later one does
                await anyio.to_thread.run_sync(warm_up_scenes, state.catalog)
            except Exception as err:  # a warm-up that fails must not stop the service
                log.warning("the scene path's warm-up failed (the first scene pays): %s", err)
        if settings.warm_up and state.ready:
            try:  # ... and the first POST /v1/align (imports, open3d, the first ICP)
                await anyio.to_thread.run_sync(warm_up_alignment)
            except Exception as err:
                log.warning("the alignment's warm-up failed (the first alignment pays): %s", err)
        # Every admitted estimate gets a worker thread at once: no hidden queue behind the gate.
        limiter = anyio.to_thread.current_default_thread_limiter()
        limiter.total_tokens = max(
            limiter.total_tokens, settings.limits.max_concurrent_requests + THREADS_BESIDES
        )
        pauses = GcPauseRecorder(metrics.observe_gc)
        pauses.install()
        # SIGTERM: streams in flight get their final result before uvicorn closes them.
        if state.drain.install():
            log.info("streams drain on SIGTERM")
        sys.setswitchinterval(settings.switch_interval_ms / 1e3)
        if settings.gc_freeze:
            log.info("froze %d start-up objects out of garbage collection",
                     freeze_startup_objects())  # fmt: skip
        try:
            yield
        finally:
            pauses.remove()
            state.decoder.close()  # the large-JSON parser's worker process, if started

    app = FastAPI(title="itnet", version=__version__, description=DESCRIPTION, lifespan=lifespan)
    app.state.service = state
    app.include_router(estimate.router)
    app.include_router(stream.router)
    app.include_router(system.router)
    app.include_router(align.router)
    app.include_router(scene.router)
    app.include_router(examples.router)
    app.include_router(page.router)  # GET /: the web page, its files under /static
    app.mount("/static", page.static_files(), name="static")
    app.add_middleware(RequestMetricsMiddleware, metrics=metrics)
    _add_error_handlers(app, metrics)
    return app


def _add_error_handlers(app: FastAPI, metrics: Metrics) -> None:
    """Every error body is ``{"detail": <one sentence>, "kind": <label>}``, counted by kind."""

    def reply(
        status: int, kind: str, detail: str, headers: dict[str, str] | None = None
    ) -> JSONResponse:
        metrics.observe_error(kind)
        return JSONResponse({"detail": detail, "kind": kind}, status_code=status, headers=headers)

    @app.exception_handler(ServiceError)
    async def service_error(request: Request, err: ServiceError) -> JSONResponse:
        return reply(err.status, err.kind, err.detail, err.headers)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, err: RequestValidationError) -> JSONResponse:
        return reply(422, "invalid_request", describe_errors(err.errors()))

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, err: StarletteHTTPException) -> JSONResponse:
        kind = {404: "not_found", 405: "method_not_allowed"}.get(err.status_code, "http")
        return reply(err.status_code, kind, str(err.detail), dict(err.headers or {}))

    @app.exception_handler(Exception)
    async def internal(request: Request, err: Exception) -> JSONResponse:
        log.exception("unhandled error on %s", request.url.path)
        return reply(500, "internal", "internal error")
