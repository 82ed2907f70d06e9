"""Anytime evaluation: accuracy after every iteration 0..K on a fixed scan set.

Any ``step`` callable can be evaluated — the torch network or the shipped ONNX graph — because
both see exactly the runtime's input: the cloud normalised by ``itnet.preprocess`` and resampled
to the model's point count with a seeded generator.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel

from itnet.metrics import is_correct, pose_errors
from itnet.model.data import ScanSet
from itnet.preprocess import (
    Normalization,
    cap_points,
    estimate_normalization,
    pose_from_normalized,
    resample,
)
from itnet.symmetry import symmetric_rotation_error_deg
from itnet.upright import held_upright, upright_starts

if TYPE_CHECKING:
    from itnet.pose.runtime import LoadedModel

# (points B x N x 3 float32, pose B x4x4 float32) -> next pose B x4x4
StepFn = Callable[[NDArray[np.float32], NDArray[np.float32]], NDArray[np.float32]]


class AnytimeReport(BaseModel):
    """Accuracy per iteration (index 0 = before any step) and error summaries."""

    iterations: list[int]
    accuracy: list[float]
    rotation_accuracy: list[float]
    translation_accuracy: list[float]
    median_rotation_deg: list[float]
    median_translation: list[float]
    scans: int

    def at(self, iteration: int) -> float:
        return self.accuracy[self.iterations.index(iteration)]


def anytime_poses(
    step: StepFn,
    scans: ScanSet,
    iterations: int,
    points: int,
    seed: int = 0,
    batch: int = 50,
    ups: NDArray | None = None,
    free_steps: int = 0,
) -> NDArray[np.float64]:
    """Poses T_canonical_from_input (S, iterations + 1, 4, 4), in the scans' own units.
    ``ups`` (S, 3): each scan's up direction as a caller gives it; the run is then held upright
    as the service holds it (``itnet.upright``; stood up from the start, or after the card's
    ``free_steps``)."""
    rng = np.random.default_rng(seed)
    norms = [estimate_normalization(c) for c in scans.clouds]
    inputs = np.stack([resample(n.apply(c), points, rng) for n, c in zip(norms, scans.clouds)])
    out = np.empty((len(inputs), iterations + 1, 4, 4))
    for start in range(0, len(inputs), batch):
        x = inputs[start : start + batch]
        up = None if ups is None else np.asarray(ups[start : start + batch], dtype=np.float64)
        pose = np.tile(np.eye(4, dtype=np.float32), (len(x), 1, 1))
        if up is not None and free_steps == 0:  # stood up as the pipeline's plan starts a run
            pose[:, :3, :3] = np.stack([upright_starts(u, 1)[0] for u in up])
        trail = [pose]
        for k in range(iterations):
            pose = step(x, pose)
            if up is not None and k >= free_steps:
                pose = np.stack([held_upright(p, u) for p, u in zip(pose, up)]).astype(np.float32)
            trail.append(pose)
        out[start : start + len(x)] = np.stack(trail, axis=1)
    for i, norm in enumerate(norms):
        out[i] = pose_from_normalized(out[i], norm)
    return out


def report(
    poses: NDArray, scans: ScanSet, symmetry: str = "none"
) -> tuple[AnytimeReport, NDArray, NDArray]:
    """Poses (S, K+1, 4, 4) -> (report, rotation errors (S, K+1), translation errors (S, K+1)).

    The rotation error is the smallest over the category's equivalent poses (``symmetry``); the
    object centre is the same for all of them."""
    rot, trans = pose_errors(poses, scans.poses[:, None], scans.radii[:, None])
    if symmetry != "none":
        rot = symmetric_rotation_error_deg(
            poses[..., :3, :3], scans.poses[:, None, :3, :3], symmetry
        )
    ok = is_correct(rot, trans)
    rep = AnytimeReport(
        iterations=list(range(poses.shape[1])),
        accuracy=[round(float(v), 4) for v in ok.mean(0)],
        rotation_accuracy=[round(float(v), 4) for v in (rot < 10).mean(0)],
        translation_accuracy=[round(float(v), 4) for v in (trans < 0.1).mean(0)],
        median_rotation_deg=[round(float(v), 3) for v in np.median(rot, 0)],
        median_translation=[round(float(v), 4) for v in np.median(trans, 0)],
        scans=len(scans.clouds),
    )
    return rep, rot, trans


def torch_step(net) -> StepFn:  # type: ignore[no-untyped-def]
    """A StepFn running an ITNet in eval mode (fp32)."""
    import torch

    device = next(net.parameters()).device  # scans stay numpy; the network may be on a GPU

    def step(points: NDArray[np.float32], pose: NDArray[np.float32]) -> NDArray[np.float32]:
        net.eval()
        with torch.no_grad():
            nxt, _ = net.step(
                torch.from_numpy(points).to(device), torch.from_numpy(pose).to(device)
            )
        return nxt.cpu().numpy()

    return step


def run_poses(
    model: LoadedModel,
    cloud: NDArray,
    starts: NDArray | None,
    seed: int,
    iterations: int = 10,
    up: NDArray | None = None,
) -> tuple[NDArray, NDArray, Normalization]:
    """One scan (N, 3), input units -> each run's pose after ``iterations`` steps (K, 4, 4),
    its points (K, n, 3), both in the normalised frame, and the normalisation: the runs as the
    engine runs them (the whole cloud sets the normalisation; one run of the card's points, or
    ``starts`` (K, 3, 3) each on its own random subset of ``min(points, 0.8 N)``), no clock.
    ``up`` (3,): the scan's up as a request gives it; the runs are then held upright after the
    card's ``up_free_steps`` (``starts`` should be ``upright_starts`` of it)."""
    from itnet.pose.cloud import Limits
    from itnet.pose.plan import ENSEMBLE_SUBSET

    rng = np.random.default_rng(seed)
    norm = estimate_normalization(cloud)
    normalized = norm.apply(cloud)
    if starts is None:
        x = cap_points(normalized, model.card.points, rng)[None]
        pose = np.eye(4, dtype=np.float32)[None]
    else:
        size = min(model.card.points, max(Limits().min_points, int(ENSEMBLE_SUBSET * len(cloud))))
        x = np.stack([cap_points(normalized, size, rng) for _ in starts])
        pose = np.tile(np.eye(4, dtype=np.float32), (len(starts), 1, 1))
        pose[:, :3, :3] = starts
    x = x.astype(np.float32)
    for k in range(iterations):
        pose, _ = model.step(x, pose)
        if up is not None and k >= model.card.up_free_steps:
            pose = held_upright(pose, up).astype(np.float32)
    return pose, x, norm
