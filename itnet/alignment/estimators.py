"""Pose estimators for ``itnet.alignment.pipeline``: IT-Net in-process, or through a running service.

Both are callables ``(cloud (N, 3), starts, iterations, subset) -> [PoseEstimate]`` (one
T_canonical_from_input, 4x4 in the cloud's units, per start), so the alignment code does not
care where the network runs. ``starts`` (B, 3, 3) are the rotations IT-Net begins from (None:
the identity only); ``iterations`` caps each run (None: the estimator's own cap, else the
model's recommendation); ``subset``: each run sees its own seeded random subset of that many
points (None: the model's point count); ``up``: which way is up in the cloud (None: not known),
each run then held upright by the engine.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from itnet.alignment.pipeline import PoseEstimate, PoseEstimator
from itnet.geometry import rigid_from_rotation_translation
from itnet.preprocess import cap_points

if TYPE_CHECKING:
    from itnet.clients import ItnetClient
    from itnet.service.runtime import LoadedModel


def in_process_estimator(
    model: LoadedModel, budget_ms: float, max_iterations: int | None = None, seed: int = 0
) -> PoseEstimator:
    """IT-Net through ``itnet.service.engine.AnytimeRun`` on a loaded model (``LoadedModel``).

    Raises ``itnet.service.engine.BadCloudError`` for a cloud the engine refuses."""
    from itnet.service.engine import AnytimeRun

    def estimate(
        points: NDArray[np.float64],
        starts: NDArray | None = None,
        iterations: int | None = None,
        subset: int | None = None,
        up: NDArray | None = None,
    ) -> list[PoseEstimate]:
        # Every start in one run: the copies of the cloud go through each step as one batch.
        cap = max_iterations if iterations is None else iterations
        run = AnytimeRun(model, points, budget_ms=budget_ms, max_iterations=cap, seed=seed,
                         starts=starts, points_per_step=subset, up=up)  # fmt: skip
        run.run_to_end()
        elapsed, stopped = run.elapsed_ms(), str(run.stopped_by)
        return [PoseEstimate(pose, run.iteration, elapsed, stopped) for pose in run.poses()]

    return estimate


def client_estimator(
    client: ItnetClient, model: str, budget_ms: float, max_iterations: int | None = None
) -> PoseEstimator:
    """IT-Net through ``itnet.clients.ItnetClient.estimate`` (binary body: float32 on the wire).

    The HTTP API always starts at the identity (stood up, with ``up``), so each start is a
    request of its own: the cloud (its subset) and its up turned by it here (about the origin:
    the service recentres it anyway), the turn composed back into the pose; the engine does the
    same with the turns in-process.
    Raises ``itnet.clients.ItnetRequestError`` when the service refuses the cloud."""

    def estimate(
        points: NDArray[np.float64],
        starts: NDArray | None = None,
        iterations: int | None = None,
        subset: int | None = None,
        up: NDArray | None = None,
    ) -> list[PoseEstimate]:
        out, cloud, rng = [], np.asarray(points), np.random.default_rng(0)
        for turn in np.eye(3)[None] if starts is None else np.asarray(starts).reshape(-1, 3, 3):
            # The same subsets, drawn the same way, as AnytimeRun's points_per_step.
            seen = cloud if subset is None else cap_points(cloud, subset, rng)
            reply = client.estimate(
                seen @ turn.T,
                budget_ms=budget_ms,
                max_iterations=max_iterations if iterations is None else iterations,
                model=model,
                binary=True,
                mirror=False,  # as in-process: a hypothesis' pose is the network's,
                centre=False,  # not finished by the mirror or the centre correction,
                ensemble=1,  # one run from this start (not the card's default ensemble),
                recheck=False,  # and not rechecked by the verifier
                up=None if up is None else turn @ np.asarray(up, dtype=np.float64),
            )
            back = rigid_from_rotation_translation(turn, np.zeros(3))
            out.append(PoseEstimate(reply.T_canonical_from_input @ back, reply.iterations,
                                    reply.elapsed_ms, reply.stopped_by))  # fmt: skip
        return out

    return estimate
