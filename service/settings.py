"""Service settings: one ``Settings(BaseSettings)``, read from ``ITNET_*`` environment variables.

Nested limits use a double underscore, e.g. ``ITNET_LIMITS__MAX_POINTS=50000``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from itnet.pose.cloud import Limits
from itnet.pose.recognition import MAX_LOOKS, SECOND_LOOKS
from itnet.pose.runtime import RuntimeOptions, default_model_dir


class LimitSettings(BaseModel):
    """What one request may ask for, and how many may run at once."""

    min_points: int = Field(default=32, ge=1, description="fewest points in a cloud")
    max_points: int = Field(default=250_000, ge=1, description="most points in a cloud")
    max_budget_ms: float = Field(
        default=10_000.0, gt=0, description="largest budget_ms, milliseconds"
    )
    max_iterations: int = Field(default=200, ge=1, description="largest max_iterations")
    max_body_bytes: int = Field(default=16 * 2**20, ge=1024, description="largest HTTP body, bytes")
    max_ws_message_bytes: int = Field(
        default=16 * 2**20, ge=1024, description="largest WebSocket message, bytes"
    )
    max_concurrent_requests: int = Field(
        default_factory=lambda: 2 * (os.cpu_count() or 1),
        ge=1,
        description="estimates in flight (HTTP + WebSocket); beyond: 503 + Retry-After. "
        "Default: 2 per CPU core, what 2 cores serve within a 50 ms budget at p99 "
        "(docs/hardening.md)",
    )
    retry_after_s: int = Field(
        default=1, ge=0, description="Retry-After of a 503 when overloaded, seconds"
    )
    ws_request_timeout_s: float = Field(
        default=10.0, gt=0, description="wait for a WebSocket's first message, seconds"
    )
    ws_send_timeout_s: float = Field(
        default=5.0,
        gt=0,
        description="a stream message the client has not taken in this time: it is gone, seconds",
    )
    body_timeout_s: float = Field(
        default=30.0,
        gt=0,
        description="the whole HTTP body must arrive within this of the request's first byte, "
        "seconds",
    )
    max_buffered_bytes: int = Field(
        default=256 * 2**20,
        ge=1024,
        description="request bodies and WebSocket requests held at once, all requests together, "
        "bytes; a request that does not fit: 503 + Retry-After before its body is read",
    )
    heavy_json_bytes: int = Field(
        default=2**20,
        ge=1,
        description="JSON bodies at least this large are parsed in a worker process, "
        "json_parse_lanes at a time",
    )
    json_parse_lanes: int = Field(
        default=1, ge=1, description="large JSON bodies parsed at once; the others wait or get 503"
    )

    @model_validator(mode="after")
    def _ordered(self) -> LimitSettings:
        if self.min_points > self.max_points:
            raise ValueError(f"min_points {self.min_points} > max_points {self.max_points}")
        return self

    def engine_limits(self) -> Limits:
        """The subset the anytime engine enforces itself."""
        return Limits(
            min_points=self.min_points,
            max_points=self.max_points,
            max_budget_ms=self.max_budget_ms,
            max_iterations=self.max_iterations,
        )


class ServerSettings(BaseModel):
    """The connection-level limits, enforced by uvicorn and ``itnet.service.guards.protocol``."""

    max_connections: int = Field(
        default=256,
        ge=1,
        description="open connections, HTTP and WebSocket; a newcomer evicts the stalest idle "
        "one (service/guards/connections.py)",
    )
    probe_connections: int = Field(
        default=16,
        ge=1,
        description="connections beyond max_connections that may ask /healthz or /readyz when "
        "every other connection is busy",
    )
    ws_buffer_bytes: int = Field(
        default=64 * 2**20,
        ge=1024,
        description="bytes of unfinished WebSocket messages held, all connections together; "
        "beyond: close 1013",
    )
    backlog: int = Field(default=512, ge=1, description="TCP accept queue length")
    keep_alive_s: int = Field(default=5, ge=1, description="idle keep-alive connection, seconds")
    header_timeout_s: float = Field(
        default=10.0, gt=0, description="request line + headers must arrive within this, seconds"
    )
    max_header_bytes: int = Field(
        default=64 * 1024, ge=1024, description="request line + headers, bytes; beyond: 431"
    )
    graceful_shutdown_s: int = Field(
        default=30, ge=1, description="SIGTERM: how long in-flight requests may finish, seconds"
    )
    ws_ping_interval_s: float = Field(
        default=20.0, gt=0, description="WebSocket ping interval, seconds"
    )
    ws_ping_timeout_s: float = Field(
        default=20.0, gt=0, description="a WebSocket without a pong in this time is closed"
    )
    ws_max_queue: int = Field(
        default=4, ge=1, description="received WebSocket messages buffered per connection"
    )


class Settings(BaseSettings):
    """Everything the service can be told. Environment: ``ITNET_<FIELD>``."""

    model_config = SettingsConfigDict(
        env_prefix="ITNET_", env_nested_delimiter="__", protected_namespaces=()
    )

    model_dir: Path = Field(
        default_factory=default_model_dir, description="folder of .onnx models to load"
    )
    default_model: str | None = Field(
        default=None,
        description="model used when a request names none (default: 'chair', or the only one)",
    )
    threads: int = Field(
        default=2, ge=1, le=64, description="onnxruntime intra-op threads per model"
    )
    concurrent_steps: int | None = Field(
        default=None,
        ge=1,
        description="steps of one model run at once, others wait (default: cores // threads)",
    )
    provider: Literal["cpu", "cuda", "tensorrt"] = Field(
        default="cpu",
        description="where the graphs run: onnxruntime's CPU, CUDA or TensorRT execution "
        "provider (the GPU ones need onnxruntime-gpu; ITNET_PROVIDER)",
    )
    batch_jobs: int = Field(
        default=64,
        ge=1,
        le=1024,
        description="steps of different requests one graph call may hold (1: no batching "
        "across requests; ITNET_BATCH_JOBS)",
    )
    warm_up: bool = Field(
        default=True,
        description="run a few steps per model at start-up, load what a first alignment needs, "
        "and run the scene path once where a classifier is loaded",
    )
    gc_freeze: bool = Field(
        default=True,
        description="after start-up, exclude the objects alive then from garbage collection "
        "(gc.freeze): full collections shrink from ~45 ms to ~1 ms (service/gc_tuning.py)",
    )
    switch_interval_ms: float = Field(
        default=0.5,
        gt=0,
        le=100,
        description="the interpreter's thread switch interval (sys.setswitchinterval): how long "
        "a run's thread, back from a network step, may wait for the GIL while the event loop "
        "answers other clients; Python's own 5 ms is a quarter of a 20 ms budget "
        "(docs/service.md)",
    )
    classify_second_looks: int = Field(
        default=SECOND_LOOKS,
        ge=1,
        le=MAX_LOOKS,
        description="model auto: a single look below the classifier's threshold is followed by "
        "this many looks in all, where they fit the budget's first half (1: never; "
        "docs/classification.md)",
    )
    limits: LimitSettings = Field(default_factory=lambda: LimitSettings())
    server: ServerSettings = Field(default_factory=lambda: ServerSettings())

    @field_validator("model_dir")
    @classmethod
    def _expand(cls, value: Path) -> Path:
        return value.expanduser()

    def runtime_options(self) -> RuntimeOptions:
        """Where the graphs run and how steps share calls (``itnet.pose.runtime``)."""
        return RuntimeOptions(self.provider, self.batch_jobs)
