"""Service settings: one ``Settings(BaseSettings)``, read from ``ITNET_*`` environment variables.

Nested limits use a double underscore, e.g. ``ITNET_LIMITS__MAX_POINTS=50000``.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from itnet.service.engine import Limits
from itnet.service.runtime import default_model_dir


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
        default=16,
        ge=1,
        description="estimates in flight (HTTP + WebSocket); beyond: 503 + Retry-After",
    )
    retry_after_s: int = Field(
        default=1, ge=0, description="Retry-After of a 503 when overloaded, seconds"
    )
    ws_request_timeout_s: float = Field(
        default=10.0, gt=0, description="wait for a WebSocket's first message, seconds"
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
    warm_up: bool = Field(default=True, description="run a few steps per model at start-up")
    limits: LimitSettings = Field(default_factory=lambda: LimitSettings())

    @field_validator("model_dir")
    @classmethod
    def _expand(cls, value: Path) -> Path:
        return value.expanduser()
