"""Pose estimators for ``itnet.alignment.pipeline``: the served pose, in-process or from a service.

``InProcessEstimator`` is a callable ``(cloud (N, 3), up (3,) or None) -> PoseEstimate``, and
poses an alignment's two clouds together (``together``: admitted as one request, run in turn on
one clock): each cloud's pose as
``itnet pose`` serves it for the request ``cloud_request`` makes of the alignment's (its share
of the alignment's budget, ``ALIGN_RUNS`` fused runs unless the request names its ensemble, each
on every step unless it asks for the card's schedule; the
verifier, mirror and centre finishes, ``up`` where given), with each run's own pose as the
alternatives; where the plan has fewer than ``alternatives`` runs (a single run, say), a second
request of that many fused runs gives them. ``POST /v1/align`` runs the same estimator on the
server's models, which is what ``itnet-align --server`` asks for.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from itnet.alignment.pipeline import POSE_SHARE, CloudEstimateError, PoseEstimate
from itnet.pose.request import PoseRequest

if TYPE_CHECKING:
    from itnet.pose.catalog import Catalog
    from itnet.pose.loop import AnytimeRun


ALIGN_RUNS = 4  # runs fused into each cloud's pose where the request names none (docs/align.md)


def cloud_request(request: PoseRequest) -> PoseRequest:
    """The pose request of each cloud of an alignment asked for with ``request`` (whose
    ``budget_ms`` is the whole alignment's): POSE_SHARE of the budget, ALIGN_RUNS fused runs
    unless it names its ensemble, every run on all its points every step unless it asks for the
    card's schedule (the choice among the hypotheses was calibrated on such runs' poses; on
    the schedule, pairs of little overlap lost 5.0 +- 3.3 points: docs/align.md)."""
    schedule = False if request.schedule is None else request.schedule
    return request.model_copy(update={"budget_ms": request.budget_ms * POSE_SHARE,
                                      "ensemble": request.ensemble or ALIGN_RUNS,
                                      "schedule": schedule})  # fmt: skip


def _with_up(request: PoseRequest, up: NDArray | None) -> PoseRequest:
    """The request with this cloud's up (None: the request's own), asking for every run's pose
    too (the alignment's other hypotheses)."""
    update: dict = {"runs": True}
    if up is not None:
        update["up"] = [float(v) for v in np.asarray(up).reshape(3)]
    return request.model_copy(update=update)


ALTERNATIVES = 4  # runs whose poses an alignment weighs at the least, per cloud
NAMES = ("A", "B")


def _estimate(replies: list[dict]) -> PoseEstimate:
    """One cloud's served pose from its reply, with the runs of every reply (the served one
    first, then a second request's alternatives)."""
    reply = replies[0]
    runs = np.concatenate([np.asarray(r["runs"], dtype=np.float64).reshape(-1, 4, 4)
                           for r in replies])  # fmt: skip
    return PoseEstimate(np.asarray(reply["T_canonical_from_input"], dtype=np.float64),
                        sum(int(r["iterations"]) for r in replies), float(reply["elapsed_ms"]),
                        str(reply["stopped_by"]), reply, runs)  # fmt: skip


class InProcessEstimator:
    """The served pose of ``cloud_request(request)`` through ``Catalog.start`` (the pose
    pipeline, in this process), its budget counted from ``started`` (a ``time.perf_counter()``
    value; default: each call's start). Where the plan fuses fewer than ``alternatives`` runs,
    a second request of that many gives the alignment its alternatives."""

    def __init__(self, catalog: Catalog, request: PoseRequest, started: float | None = None,
                 alternatives: int = ALTERNATIVES) -> None:  # fmt: skip
        self.catalog, self.started, self.alternatives = catalog, started, alternatives
        self.request = cloud_request(request)

    def __call__(self, points: NDArray[np.float64], up: NDArray | None = None) -> PoseEstimate:
        """One cloud's pose (``together`` of one). Raises ``itnet.pose.errors.PoseError`` for a
        cloud or request the pipeline refuses."""
        try:
            return self.together([points], [up])[0]
        except CloudEstimateError as err:
            raise err.__cause__ from None  # type: ignore[misc]

    def together(self, clouds: list[NDArray[np.float64]],
                 ups: list[NDArray | None]) -> list[PoseEstimate]:  # fmt: skip
        """The poses of an alignment's clouds, admitted together as one request and run in turn.
        Raises CloudEstimateError naming the cloud refused (``__cause__``: the PoseError)."""
        asked = [_with_up(self.request, up) for up in ups]
        replies = [[r] for r in self._together(clouds, asked)]
        if int(replies[0][0]["ensemble"]) < self.alternatives:
            more = [r.model_copy(update={"ensemble": self.alternatives}) for r in asked]
            for got, reply in zip(replies, self._together(clouds, more)):
                got.append(reply)
        return [_estimate(r) for r in replies]

    def _together(self, clouds: list[NDArray], requests: list[PoseRequest]) -> list[dict]:
        """The clouds' poses, admitted as one request and run in turn on one clock: the k-th
        of n may end at (k + 1) / n of the budget, so the first cannot spend the others'."""
        from itnet.pose.errors import PoseError

        started = time.perf_counter() if self.started is None else self.started
        runs: list[AnytimeRun] = []
        for k, (name, points, asked) in enumerate(zip(NAMES, clouds, requests)):
            share = asked.budget_ms * (k + 1) / len(clouds)
            try:
                runs.append(self.catalog.start(points, asked.model_copy(update={"budget_ms": share}),
                                               started))  # fmt: skip
            except PoseError as err:
                raise CloudEstimateError(name, err) from err
        try:
            return self.catalog.pose_together(runs)
        except PoseError as err:
            unserved = [k for k, run in enumerate(runs) if run.iteration == 0]
            raise CloudEstimateError(NAMES[unserved[0] if unserved else 0], err) from err


def in_process_estimator(catalog: Catalog, request: PoseRequest, started: float | None = None,
                         alternatives: int = ALTERNATIVES) -> InProcessEstimator:  # fmt: skip
    """``InProcessEstimator(catalog, request, started, alternatives)``."""
    return InProcessEstimator(catalog, request, started, alternatives)
