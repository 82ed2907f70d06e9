"""Prometheus metrics of one app (its own registry, so several apps can live in one process).

* ``itnet_requests_total{endpoint,status}``: HTTP requests by route and status; WebSocket streams
  by route and close code.
* ``itnet_request_duration_seconds{endpoint}``: wall time per request/stream (histogram).
* ``itnet_iterations{model}``: network steps per estimate (histogram).
* ``itnet_runs_total{model,stopped_by}``: finished runs by stop reason (``disconnected`` when a
  WebSocket client left).
* ``itnet_errors_total{kind}``: refused or failed requests by error kind.
* ``itnet_in_flight``: estimates running now.

With ``itnet serve --workers N`` every worker is its own process: ``serve`` points
``PROMETHEUS_MULTIPROC_DIR`` at a fresh folder, each worker's values go to files there
(prometheus_client's multiprocess mode), and ``/metrics`` from any worker reports the sum over
all of them. A worker that died (and was restarted by uvicorn's supervisor) leaves its last
``itnet_in_flight`` behind; ``render`` forgets the live-mode gauges of processes that no longer
exist (``forget_dead_workers``), while counters keep a dead worker's counts, as they should.
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Awaitable, Callable, MutableMapping
from pathlib import Path
from typing import Any

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
)
from prometheus_client.multiprocess import MultiProcessCollector, mark_process_dead

# Set (by ``service.server.run`` with several workers, or by the operator) before the worker
# processes start: prometheus_client reads it when it is imported.
MULTIPROCESS_DIR_ENV = "PROMETHEUS_MULTIPROC_DIR"


def multiprocess_dir() -> str | None:
    """The folder where the workers' metric values add up, if several processes serve."""
    return os.environ.get(MULTIPROCESS_DIR_ENV) or None


# A live-mode gauge's file in the multiprocess folder: gauge_livesum_<pid>.db and the like.
_LIVE_GAUGE_FILE = re.compile(r"^gauge_live[a-z]*_(\d+)\.db$")


def _process_exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def forget_dead_workers(folder: str) -> list[int]:
    """Remove the live-mode gauge files (``itnet_in_flight``) of processes that no longer exist,
    so a dead worker's last value stops counting. Returns the pids forgotten.

    prometheus_client leaves this to ``mark_process_dead``, which a supervisor is meant to call
    when a worker exits; uvicorn's has no hook for it, so the scrape does it.
    """
    dead = set()
    for path in Path(folder).glob("gauge_live*_*.db"):
        match = _LIVE_GAUGE_FILE.match(path.name)
        if match and not _process_exists(int(match.group(1))):
            dead.add(int(match.group(1)))
    for pid in dead:
        mark_process_dead(pid, folder)
    return sorted(dead)


Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

LATENCY_BUCKETS = (
    0.002,
    0.005,
    0.01,
    0.02,
    0.035,
    0.05,
    0.075,
    0.1,
    0.15,
    0.25,
    0.5,
    1,
    2.5,
    5,
    10,
)
ITERATION_BUCKETS = (0, 1, 2, 3, 5, 8, 10, 15, 20, 30, 50, 100, 200)
# Scope key: time.perf_counter() when the request reached the app (the budget counts from it).
ARRIVED = "itnet.arrived"


GC_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1)


class Metrics:
    """The service's counters and histograms, in a private registry."""

    content_type = CONTENT_TYPE_LATEST

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.requests = Counter(
            "itnet_requests", "Requests by endpoint and status", ["endpoint", "status"], registry=r
        )
        self.latency = Histogram(
            "itnet_request_duration_seconds", "Request wall time", ["endpoint"],
            buckets=LATENCY_BUCKETS, registry=r,
        )  # fmt: skip
        self.iterations = Histogram(
            "itnet_iterations", "Network steps per estimate", ["model"],
            buckets=ITERATION_BUCKETS, registry=r,
        )  # fmt: skip
        self.runs = Counter(
            "itnet_runs", "Finished runs by stop reason", ["model", "stopped_by"], registry=r
        )
        self.errors = Counter("itnet_errors", "Errors by kind", ["kind"], registry=r)
        self.in_flight = Gauge(
            "itnet_in_flight", "Estimates running now", registry=r,
            multiprocess_mode="livesum",  # with several workers: the sum over the live ones
        )  # fmt: skip
        self.gc_pause = Histogram(
            "itnet_gc_pause_seconds", "Garbage-collector passes by generation", ["generation"],
            buckets=GC_BUCKETS, registry=r,
        )  # fmt: skip

    def observe_gc(self, generation: int, seconds: float) -> None:
        self.gc_pause.labels(str(generation)).observe(seconds)

    def observe_request(self, endpoint: str, status: int | str, seconds: float) -> None:
        self.requests.labels(endpoint, str(status)).inc()
        self.latency.labels(endpoint).observe(seconds)

    def observe_run(self, model: str, iterations: int, stopped_by: str) -> None:
        self.iterations.labels(model).observe(iterations)
        self.runs.labels(model, stopped_by).inc()

    def observe_error(self, kind: str) -> None:
        self.errors.labels(kind).inc()

    def render(self) -> bytes:
        """The Prometheus text exposition format (version 0.0.4): this app's registry, or every
        worker's values where several processes serve (``multiprocess_dir``)."""
        folder = multiprocess_dir()
        if folder is None:
            return generate_latest(self.registry)
        forget_dead_workers(folder)
        every_worker = CollectorRegistry()
        MultiProcessCollector(every_worker, path=folder)
        return generate_latest(every_worker)


class RequestMetricsMiddleware:
    """ASGI middleware: counts every HTTP request by route template and status, and times it.

    Unrouted paths share the label ``unmatched`` so that scanners cannot blow up the label set.
    WebSocket streams are counted by their own handler (their "status" is the close code).
    """

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app, self.metrics = app, metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start, status = time.perf_counter(), 500
        scope.setdefault(ARRIVED, start)  # the protocol records the first byte's arrival

        async def send_recording_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_recording_status)
        finally:
            route = scope.get("route")
            endpoint = getattr(route, "path", None) or "unmatched"
            self.metrics.observe_request(endpoint, status, time.perf_counter() - start)
