"""Runs of the pose pipeline for tests: a loaded model, a cloud and request fields by name."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from itnet.pose.cloud import Limits
from itnet.pose.loop import AnytimeRun
from itnet.pose.plan import plan
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import LoadedModel


def run_with(
    model: LoadedModel,
    points: ArrayLike,
    started: float | None = None,
    reserve_ms: float = 0.0,
    limits: Limits = Limits(),
    converge: tuple[float, float] | None = None,
    seed: int = 0,
    **fields: Any,
) -> AnytimeRun:
    """``AnytimeRun(plan(model, PoseRequest(**fields), limits), points, started, reserve_ms)``,
    with arrays allowed for ``up`` and ``viewpoint``; ``converge``: the plan's convergence
    tolerances instead of the pipeline's ((0, 0): never)."""
    for name in ("up", "viewpoint"):
        if fields.get(name) is not None and not isinstance(fields[name], str):
            fields[name] = [float(v) for v in np.asarray(fields[name]).ravel()]
    planned = plan(model, PoseRequest(**fields), limits, seed=seed)
    if converge is not None:
        planned = replace(planned, converge=converge)
    return AnytimeRun(planned, points, started, reserve_ms)
