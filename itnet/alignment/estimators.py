"""Pose estimators for ``itnet.alignment.pipeline``: the served pose, in-process or from a service.

Both are callables ``(cloud (N, 3), up (3,) or None) -> PoseEstimate``: the cloud's pose as
``itnet pose`` serves it (the same ``PoseRequest``, planned the same way: the card's runs, its
verifier, mirror and centre finishes, ``up`` where given), so the alignment code does not care
where the network runs, and the two give the same answer by construction.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from itnet.alignment.pipeline import PoseEstimate, PoseEstimator
from itnet.pose.request import PoseRequest

if TYPE_CHECKING:
    from itnet.clients import ItnetClient
    from itnet.pose.catalog import Catalog


def _with_up(request: PoseRequest, up: NDArray | None) -> PoseRequest:
    """The request with this cloud's up (None: the request's own)."""
    if up is None:
        return request
    return request.model_copy(update={"up": [float(v) for v in np.asarray(up).reshape(3)]})


def in_process_estimator(catalog: Catalog, request: PoseRequest) -> PoseEstimator:
    """The served pose through ``Catalog.start`` (one run of the pose pipeline per cloud).
    Raises ``itnet.pose.errors.PoseError`` for a cloud or request the pipeline refuses."""

    def estimate(points: NDArray[np.float64], up: NDArray | None = None) -> PoseEstimate:
        run = catalog.start(points, _with_up(request, up))
        run.run_to_end()
        run.check_served()
        result = run.result()
        return PoseEstimate(np.asarray(result["T_canonical_from_input"]), run.iteration,
                            run.elapsed_ms(), str(run.stopped_by), result)  # fmt: skip

    return estimate


def client_estimator(client: ItnetClient, request: PoseRequest) -> PoseEstimator:
    """The served pose through ``itnet.clients.ItnetClient.estimate`` (binary body: float32 on
    the wire). Raises ``itnet.clients.ItnetRequestError`` when the service refuses the cloud."""

    def estimate(points: NDArray[np.float64], up: NDArray | None = None) -> PoseEstimate:
        reply = client.estimate(points, _with_up(request, up), binary=True)
        return PoseEstimate(reply.T_canonical_from_input, reply.iterations, reply.elapsed_ms,
                            reply.stopped_by, reply.raw)  # fmt: skip

    return estimate
