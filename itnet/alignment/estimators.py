"""Pose estimators for ``itnet.alignment.pipeline``: the served pose, in-process or from a service.

Both are callables ``(cloud (N, 3), up (3,) or None) -> PoseEstimate``: the cloud's pose as
``itnet pose`` serves it (the same ``PoseRequest``, planned the same way: the card's runs, its
verifier, mirror and centre finishes, ``up`` where given), with each run's own pose as the
alternatives; where the card's plan has fewer than ``alternatives`` runs (a single run, say), a
second request of that many fused runs gives them. The alignment code does not care where the
network runs, and the two give the same answer by construction.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from itnet.alignment.pipeline import PoseEstimate, PoseEstimator
from itnet.pose.request import PoseRequest

if TYPE_CHECKING:
    from itnet.clients import ItnetClient
    from itnet.pose.catalog import Catalog


def _with_up(request: PoseRequest, up: NDArray | None) -> PoseRequest:
    """The request with this cloud's up (None: the request's own), asking for every run's pose
    too (the alignment's other hypotheses)."""
    update: dict = {"runs": True}
    if up is not None:
        update["up"] = [float(v) for v in np.asarray(up).reshape(3)]
    return request.model_copy(update=update)


ALTERNATIVES = 4  # runs whose poses an alignment weighs at the least, per cloud


def _served(serve: Callable[[PoseRequest], dict], request: PoseRequest, alternatives: int,
            ) -> PoseEstimate:  # fmt: skip
    """The served pose of ``request`` (``serve``: request -> reply), its runs, and the runs of
    a second request of ``alternatives`` fused runs where the first had fewer."""
    reply = serve(request)
    runs = [np.asarray(reply["runs"], dtype=np.float64).reshape(-1, 4, 4)]
    iterations = int(reply["iterations"])
    if int(reply["ensemble"]) < alternatives:
        more = serve(request.model_copy(update={"ensemble": alternatives}))
        runs.append(np.asarray(more["runs"], dtype=np.float64).reshape(-1, 4, 4))
        iterations += int(more["iterations"])
    return PoseEstimate(np.asarray(reply["T_canonical_from_input"], dtype=np.float64), iterations,
                        float(reply["elapsed_ms"]), str(reply["stopped_by"]), reply,
                        np.concatenate(runs))  # fmt: skip


def in_process_estimator(catalog: Catalog, request: PoseRequest,
                         alternatives: int = ALTERNATIVES) -> PoseEstimator:  # fmt: skip
    """The served pose through ``Catalog.start`` (the pose pipeline, in this process). Raises
    ``itnet.pose.errors.PoseError`` for a cloud or request the pipeline refuses."""

    def estimate(points: NDArray[np.float64], up: NDArray | None = None) -> PoseEstimate:
        return _served(lambda asked: catalog.pose(points, asked), _with_up(request, up),
                       alternatives)  # fmt: skip

    return estimate


def client_estimator(client: ItnetClient, request: PoseRequest,
                     alternatives: int = ALTERNATIVES) -> PoseEstimator:  # fmt: skip
    """The served pose through ``itnet.clients.ItnetClient.estimate`` (binary body: float32 on
    the wire). Raises ``itnet.clients.ItnetRequestError`` when the service refuses the cloud."""

    def estimate(points: NDArray[np.float64], up: NDArray | None = None) -> PoseEstimate:
        def serve(asked: PoseRequest) -> dict:
            return client.estimate(points, asked, binary=True).raw

        return _served(serve, _with_up(request, up), alternatives)

    return estimate
