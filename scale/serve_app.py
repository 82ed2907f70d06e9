"""The itnet service as a Ray Serve application: ``Gateway`` (HTTP entry) -> ``Estimator`` replicas.

    serve run itnet.scale.serve_app:app                      # 2 replicas, 1 thread each
    serve run itnet.scale.serve_app:build_app replicas=4 threads=2
    serve run deploy/ray/serve.yaml                          # the same, from a config file

Same HTTP API as ``itnet serve`` on Serve's port (8000): ``POST /v1/estimate`` (JSON and
binary), ``WS /v1/estimate/stream``, ``POST /v1/align``, ``POST /v1/scene``, ``GET /v1/models``, ``/healthz``, ``/readyz``, ``/metrics``
(that one per replica). Each reply names the replica that answered in ``X-Itnet-Replica``.
docs/scale.md says when to use it and what to set.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field, model_validator
from ray.serve import Application

from itnet.scale.gateway import Gateway
from itnet.scale.replica import Estimator


class ServeArgs(BaseModel):
    """What ``serve run ...:build_app key=value`` (or a config's ``args``) may set."""

    replicas: int = Field(2, ge=1, description="Estimator replicas (fixed, unless autoscaling)")
    min_replicas: int | None = Field(None, ge=0, description="autoscaling: fewest replicas")
    max_replicas: int | None = Field(None, ge=1, description="autoscaling: most replicas")
    target_ongoing_requests: float = Field(
        2.0, gt=0, description="autoscaling: requests in flight per replica to aim for"
    )
    threads: int = Field(1, ge=1, description="onnxruntime threads (= CPUs reserved) per replica")
    max_ongoing_requests: int = Field(
        4, ge=1, description="requests one replica runs at once (more wait in Serve's queue)"
    )
    max_queued_requests: int = Field(
        64, ge=-1, description="requests waiting for a replica; beyond: 503 + Retry-After"
    )
    attempts: int = Field(3, ge=1, description="replicas tried when the one serving dies")
    settings: dict[str, Any] = Field(
        default_factory=dict, description="itnet Settings for each replica (else ITNET_* env)"
    )

    @model_validator(mode="after")
    def _bounds(self) -> ServeArgs:
        if (self.min_replicas is None) != (self.max_replicas is None):
            raise ValueError("set both min_replicas and max_replicas, or neither")
        if self.min_replicas is not None and self.max_replicas < self.min_replicas:  # type: ignore[operator]
            raise ValueError("max_replicas must be at least min_replicas")
        return self

    def scaling(self) -> dict[str, Any]:
        """``Estimator.options`` for a fixed count, or an autoscaling range."""
        if self.max_replicas is None:
            return {"num_replicas": self.replicas}
        return {
            "autoscaling_config": {
                "min_replicas": self.min_replicas,
                "initial_replicas": max(
                    self.min_replicas or 0, min(self.replicas, self.max_replicas)
                ),
                "max_replicas": self.max_replicas,
                "target_ongoing_requests": self.target_ongoing_requests,
            }
        }


def build_app(args: dict[str, Any] | None = None) -> Application:
    """The application from builder arguments (strings from the command line are converted)."""
    a = ServeArgs.model_validate(args or {})
    from itnet.service.settings import Settings

    settings = {"threads": a.threads, "concurrent_steps": 1, **a.settings}
    limits = Settings(**settings).limits  # checked here, once, rather than in every replica
    estimator = Estimator.options(
        **a.scaling(),
        ray_actor_options={"num_cpus": a.threads},
        max_ongoing_requests=a.max_ongoing_requests,
        max_queued_requests=a.max_queued_requests,
    ).bind(settings)
    return Gateway.bind(estimator, a.attempts, limits.max_body_bytes, limits.retry_after_s)


app = build_app()
