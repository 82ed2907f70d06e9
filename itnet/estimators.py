"""Pose estimators for ``itnet.alignment``: IT-Net in-process, or through a running service.

Both are callables ``cloud (N, 3) -> PoseEstimate`` (T_canonical_from_input, 4x4, the cloud's
units), so the alignment code does not care where the network runs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from itnet.alignment import PoseEstimate, PoseEstimator

if TYPE_CHECKING:
    from itnet.clients import ItnetClient
    from itnet.service.runtime import LoadedModel


def in_process_estimator(
    model: LoadedModel, budget_ms: float, max_iterations: int | None = None, seed: int = 0
) -> PoseEstimator:
    """IT-Net through ``itnet.service.engine.AnytimeRun`` on a loaded model (``LoadedModel``).

    Raises ``itnet.service.engine.BadCloudError`` for a cloud the engine refuses."""
    from itnet.service.engine import AnytimeRun

    def estimate(points: NDArray[np.float64]) -> PoseEstimate:
        run = AnytimeRun(
            model, points, budget_ms=budget_ms, max_iterations=max_iterations, seed=seed
        )
        last = run.run_to_end()
        return PoseEstimate(last.pose, run.iteration, run.elapsed_ms(), str(run.stopped_by))

    return estimate


def client_estimator(
    client: ItnetClient, model: str, budget_ms: float, max_iterations: int | None = None
) -> PoseEstimator:
    """IT-Net through ``itnet.clients.ItnetClient.estimate`` (binary body: float32 on the wire).

    Raises ``itnet.clients.ItnetRequestError`` when the service refuses the cloud."""

    def estimate(points: NDArray[np.float64]) -> PoseEstimate:
        reply = client.estimate(
            points, budget_ms=budget_ms, max_iterations=max_iterations, model=model, binary=True
        )
        return PoseEstimate(reply.T_canonical_from_input, reply.iterations, reply.elapsed_ms,
                            reply.stopped_by)  # fmt: skip

    return estimate
