"""Align cloud A onto cloud B: each cloud's served pose, hypotheses, ICP, the chosen one.

The steps (the policy is explained in ``itnet.alignment.hypotheses``)::

    pose_a = estimate(A)          # the pose ``itnet pose`` serves: the same request and plan,
    pose_b = estimate(B)          # in-process or through a service
    hypotheses = inv(T_b) · S · T_a  for every pose T_a of A and T_b of B (the served one first,
                 then each run's) and every symmetry S of the category (identity first)
    candidates = the distinct ones, best by a loose fit        # ``hypotheses.distinct``
    each       = ICP(candidate)                                # only with refine=True
    chosen     = the composed poses (S = identity), unless with ICP another candidate fits
                 clearly better (by ``switch_margin`` of the points)

Why the served poses. A category-level pose needs no overlap between the two views, which
correspondence-based registration does; the pose pipeline's finishing stages (fused runs, the
verifier, the mirror and centre finishes) make each pose as good as the category's model can
give it, and composing two such poses is the alignment. The symmetric hypotheses and ICP only
get a say where the geometry clearly prefers one of them: a loose overlap score picks wrong
symmetric twins of low-overlap pairs more often than the poses are wrong.

Where the caller knows which way is up in a cloud (``up_a``, ``up_b``: gravity from an IMU, a
floor's normal), its pose is estimated held upright (``itnet.upright``). Models whose card
requires up (the night stand) align only this way.

The pose estimator is passed in (a callable), so this module does no I/O and loads no model: the
CLI gives it an in-process pipeline or an HTTP client, the benchmark the same.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.alignment.hypotheses import (
    Hypothesis,
    build_hypotheses,
    choose,
    confidence,
    distinct,
    symmetry_rotations,
)
from itnet.alignment.overlap import Cloud, overlap, sample
from itnet.geometry import rotation_angle_deg
from itnet.preprocess import estimate_normalization
from itnet.upright import unit_up


@dataclass(frozen=True)
class PoseEstimate:
    """One cloud's served pose: T_canonical_from_input (4x4, input units), how it went, and the
    whole reply (``result``: what the finishing stages did)."""

    T_canonical_from_input: NDArray[np.float64]
    iterations: int
    elapsed_ms: float
    stopped_by: str
    result: dict = field(default_factory=dict, repr=False)
    runs: NDArray[np.float64] | None = field(default=None, repr=False)  # (R, 4, 4): each run's

    def candidates(self) -> NDArray[np.float64]:
        """The served pose, then each run's own (R + 1, 4, 4): the alignment's alternatives."""
        poses = [self.T_canonical_from_input[None]]
        if self.runs is not None and len(self.runs):
            poses.append(np.asarray(self.runs, dtype=np.float64).reshape(-1, 4, 4))
        return np.concatenate(poses)

    def to_dict(self) -> dict:
        extra = {k: self.result[k] for k in ("model", "ensemble", "skipped") if k in self.result}
        return {"T_canonical_from_input": self.T_canonical_from_input.tolist(),
                "iterations": self.iterations, "elapsed_ms": round(self.elapsed_ms, 3),
                "stopped_by": self.stopped_by, **extra}  # fmt: skip


class PoseEstimator(Protocol):
    """The served pose of one cloud (N, 3), held upright by ``up`` (3,; None: free)."""

    def __call__(self, points: NDArray[np.float64], up: NDArray | None = ...) -> PoseEstimate: ...


class CloudEstimateError(Exception):
    """Estimating the pose of cloud ``cloud`` ('A' or 'B') failed; ``__cause__`` says why."""

    def __init__(self, cloud: str, cause: Exception) -> None:
        self.cloud = cloud
        super().__init__(f"cloud {cloud}: {cause}")


# A rival hypothesis replaces the composed poses only where it fits this much more of the points
# (docs/align.md: chosen on validation pairs).
SWITCH_MARGIN = 0.1


@dataclass(frozen=True)
class AlignOptions:
    """Knobs of ``align_clouds``. Distances are fractions of B's RMS radius about its centroid
    (``itnet.preprocess``), so they work in any unit."""

    symmetry: str = "yaw90"  # a name in itnet.symmetry.SYMMETRY_NAMES
    refine: bool = False
    candidates: int = 12  # distinct hypotheses kept (and refined, with refine) after ranking
    finalists: int = 4  # with refine: candidates that get ICP's fine stage, the best after its
    # coarse one (all of them when finalists >= candidates); the composed poses always do
    coarse_points: int | None = 200  # points of A in ICP's coarse stage (None: all)
    distinct_deg: float = 30.0  # hypotheses closer than this (and distinct_shift) count as one
    distinct_shift: float = 0.3
    icp_distance: float = 0.1  # ICP's final correspondence cut-off (the first stage: twice it)
    icp_tolerance: float = 1e-4  # ICP stops once fitness and RMSE change less than this
    inlier_distance: float = 0.05  # the final score's inlier distance
    rank_points: int = 32  # points of each cloud the loose ranking measures
    score_points: int = 300  # points of each cloud the final score measures
    switch_margin: float = SWITCH_MARGIN  # another candidate is chosen over the composed poses
    # only where its fitness is higher by this much (a share of the points)
    voxel: float | None = None  # ICP downsampling; None: 0.05 above 20,000 points, else none
    seed: int = 0


TREE_POINTS = 20_000  # points of each cloud in the scoring KD-trees (a random subset beyond)


@dataclass
class Alignment:
    """The answer: T_b_from_a (4x4, moves A onto B, B's units) and how it was reached."""

    T_b_from_a: NDArray[np.float64]
    pose_a: PoseEstimate  # A's served pose
    pose_b: PoseEstimate
    hypotheses: list[Hypothesis]  # the candidates, scored (and refined, with refine)
    chosen: int
    confidence: dict[str, float]
    timings_ms: dict[str, float] = field(default_factory=dict)  # itnet, rank, refine, score, total
    iterations: int = 0  # IT-Net steps of both clouds' poses
    considered: int = 0  # hypotheses ranked before the candidates were picked
    scale: float = 1.0  # B's RMS radius about its centroid (the unit of the relative distances)
    inlier_distance: float = 0.0  # the score's inlier distance, B's units
    icp_distance: float = 0.0  # ICP's final correspondence distance, B's units (0: no ICP)

    def to_dict(self) -> dict:
        """JSON form (the CLI's ``--json``)."""
        t = self.T_b_from_a
        return {
            "T_b_from_a": t.tolist(),
            "rotation_deg": round(float(rotation_angle_deg(t[:3, :3])), 4),
            "translation": t[:3, 3].tolist(),
            "iterations": self.iterations,
            "elapsed_ms": round(self.timings_ms.get("total", 0.0), 3),
            "timings_ms": {k: round(v, 3) for k, v in self.timings_ms.items()},
            **self.confidence,
            "hypothesis": self.hypotheses[self.chosen].source,
            "considered": self.considered,
            "scale": float(f"{self.scale:.5g}"),
            "inlier_distance": float(f"{self.inlier_distance:.5g}"),
            "icp_distance": float(f"{self.icp_distance:.5g}"),
            "refined": self.hypotheses[self.chosen].initial is not None,
            "T_canonical_from_a": self.pose_a.to_dict(),
            "T_canonical_from_b": self.pose_b.to_dict(),
            "hypotheses": [h.to_dict() for h in self.hypotheses],
        }


def _pose(estimate: PoseEstimator, points: NDArray, name: str, up: NDArray | None) -> PoseEstimate:
    """The cloud's served pose; what the estimator raises comes back as CloudEstimateError."""
    try:
        return estimate(points, up)
    except Exception as err:  # the estimator's own errors, labelled with the cloud they concern
        raise CloudEstimateError(name, err) from err


def align_clouds(
    points_a: ArrayLike,
    points_b: ArrayLike,
    estimate: PoseEstimator,
    options: AlignOptions,
    up_a: ArrayLike | None = None,
    up_b: ArrayLike | None = None,
) -> Alignment:
    """Cloud A (N, 3) and B (M, 3), each in its own frame and unit-consistent -> Alignment.
    ``up_a``, ``up_b`` (3,, any length): which way is up in each cloud, where known (see the
    module); ValueError for one that is not a direction.

    ``estimate`` maps a cloud (K, 3) to its served pose (``PoseEstimator``); what it raises
    comes back as CloudEstimateError (``__cause__``: the original). Raises ``itnet.alignment.refine.RefineUnavailable``
    when refinement needs open3d and it is absent.
    """
    if options.candidates < 1:
        raise ValueError("candidates must be >= 1")
    start = time.perf_counter()
    ups = [None if up is None else unit_up(up) for up in (up_a, up_b)]
    a = np.asarray(points_a, dtype=np.float64)
    b = np.asarray(points_b, dtype=np.float64)
    pose_a = _pose(estimate, a, "A", ups[0])
    pose_b = _pose(estimate, b, "B", ups[1])
    t_itnet = time.perf_counter()

    scale = estimate_normalization(b).scale
    # KD-trees on at most TREE_POINTS of each cloud: a 100,000-point scan scores the same on a
    # fifth of its points, and its tree builds in a fraction of the time.
    cloud_a = Cloud(sample(a, TREE_POINTS, options.seed))
    cloud_b = Cloud(sample(b, TREE_POINTS, options.seed + 1))
    every = build_hypotheses(
        pose_a.candidates(), pose_b.candidates(), symmetry_rotations(options.symmetry)
    )
    # Rank at ICP's first-stage distance, where an unrefined estimate still lands on B.
    loose, _ = overlap(np.array([h.T_b_from_a for h in every]), cloud_a, cloud_b,
                       2 * options.icp_distance * scale, options.rank_points, options.seed)  # fmt: skip
    for h, fit in zip(every, loose):
        h.loose_fitness = float(fit)
    keep = distinct(every, loose, options.candidates, scale, options.distinct_deg,
                    options.distinct_shift)  # fmt: skip
    # The composed poses (every[0]) always stay, first: they are the answer unless ICP shows
    # clearly better.
    rivals = [every[k] for k in keep if k != 0][: options.candidates - 1]
    hypotheses = [every[0], *rivals]
    t_rank = time.perf_counter()

    if options.refine:
        from itnet.alignment.refine import IcpRefiner

        voxel = options.voxel
        if voxel is None:
            voxel = 0.05 if max(len(a), len(b)) > 20_000 else 0.0
        refiner = IcpRefiner(a, b, options.icp_distance * scale, voxel=voxel * scale,
                             tolerance=options.icp_tolerance,
                             coarse_points=options.coarse_points)  # fmt: skip
        # Coarse stage for every candidate, fine stage for the finalists that fit best after it.
        coarse = [refiner.refine(h.T_b_from_a, slice(1)) for h in hypotheses]
        fit, _ = overlap(np.array([r.T_b_from_a for r in coarse]), cloud_a, cloud_b,
                         options.inlier_distance * scale, options.score_points, options.seed)  # fmt: skip
        finalists = {0, *np.argsort(-fit, kind="stable")[: options.finalists].tolist()}
        for k, (h, first) in enumerate(zip(hypotheses, coarse)):
            refined = refiner.refine(first.T_b_from_a, slice(1, None)) if k in finalists else first
            h.initial, h.T_b_from_a = h.T_b_from_a, refined.T_b_from_a
            h.icp = {"fitness": round(refined.fitness, 4), "rmse": float(f"{refined.rmse:.5g}")}
            h.source += "+icp"
    t_refine = time.perf_counter()

    fitness, rmse = overlap(np.array([h.T_b_from_a for h in hypotheses]), cloud_a, cloud_b,
                            options.inlier_distance * scale, options.score_points, options.seed)  # fmt: skip
    for h, fit, err in zip(hypotheses, fitness, rmse):
        h.fitness, h.rmse = float(fit), float(err)
    # A rival replaces the composed poses only where, refined, it fits clearly better; without
    # ICP the composed poses stand (validation pairs: 72% composed, 70% by the loose ranking).
    chosen = choose(hypotheses, options.switch_margin) if options.refine else 0
    done = time.perf_counter()
    return Alignment(
        T_b_from_a=hypotheses[chosen].T_b_from_a,
        pose_a=pose_a,
        pose_b=pose_b,
        hypotheses=hypotheses,
        chosen=chosen,
        confidence=confidence(hypotheses, chosen, scale),
        timings_ms={
            "itnet": (t_itnet - start) * 1e3,
            "rank": (t_rank - t_itnet) * 1e3,
            "refine": (t_refine - t_rank) * 1e3,
            "score": (done - t_refine) * 1e3,
            "total": (done - start) * 1e3,
        },
        iterations=pose_a.iterations + pose_b.iterations,
        considered=len(every),
        scale=scale,
        inlier_distance=options.inlier_distance * scale,
        icp_distance=options.icp_distance * scale if options.refine else 0.0,
    )
