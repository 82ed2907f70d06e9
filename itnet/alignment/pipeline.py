"""Align cloud A onto cloud B: IT-Net from several starts, hypotheses, ICP, the chosen one.

The steps (the policy is explained in ``itnet.alignment.hypotheses``)::

    poses_a = estimate(A, starts=turns, subset=points)   # IT-Net, in-process or a service
    poses_b = estimate(B, starts=turns, subset=points)
    hypotheses = inv(poses_b[j]) · S · poses_a[i]  for every i, j and symmetry S of the category
    candidates = the best few distinct ones by a loose fit         # ``itnet.alignment.hypotheses.distinct``
    each       = ICP(candidate)                                    # only with refine=True
    chosen     = the best by a tight fit; confidence from its fit and its margin over rivals

Why several starts. IT-Net is iterative, and where it ends depends on where it begins: a sparse
or ambiguous view ends in the right basin from some starts and not from others. The runs start
from turns about the sensor's viewing axis (z of a camera frame: the clouds IT-Net was trained
on look along it, so a turn about it keeps the view looking like one it knows), each on its own
random subset of ``points`` points of the cloud (192, a little sparser than the 256 the
model was trained at: as many pairs aligned, for less); in-process, the starts go through each
step as one batch. ``docs/align.md`` has the measurements behind the defaults (starts,
iterations per run, candidates).

Where the caller knows which way is up in a cloud (``up_a``, ``up_b``: gravity from an IMU, a
floor's normal), its runs start from turns about that direction instead, 360/starts degrees apart
and untilted, and each pose is held upright (``itnet.upright``): only yaw and position are left
to estimate, and the hypotheses keep both clouds' ups together. Models whose card requires up
(the night stand) align only this way.

The pose estimator is passed in (a callable), so this module does no I/O and loads no model: the
CLI gives it an in-process ``AnytimeRun`` or an HTTP client, the benchmark the same.
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
from itnet.geometry import rotation_angle_deg, viewing_axis_turns
from itnet.preprocess import estimate_normalization
from itnet.upright import turns_about, unit_up


@dataclass(frozen=True)
class PoseEstimate:
    """One IT-Net run: T_canonical_from_input (4x4, input units) and how it went."""

    T_canonical_from_input: NDArray[np.float64]
    iterations: int
    elapsed_ms: float
    stopped_by: str

    def to_dict(self) -> dict:
        return {"T_canonical_from_input": self.T_canonical_from_input.tolist(),
                "iterations": self.iterations, "elapsed_ms": round(self.elapsed_ms, 3),
                "stopped_by": self.stopped_by}  # fmt: skip


class PoseEstimator(Protocol):
    """IT-Net on one cloud (N, 3) from each rotation of ``starts`` (B, 3, 3; None: the identity
    alone), for at most ``iterations`` steps (None: the estimator's default), each run on its own
    random subset of ``subset`` points (None: the model's count), held upright by ``up`` (3,;
    None: free) -> B PoseEstimates."""

    def __call__(
        self,
        points: NDArray[np.float64],
        starts: NDArray | None = ...,
        iterations: int | None = ...,
        subset: int | None = ...,
        up: NDArray | None = ...,
    ) -> list[PoseEstimate]: ...


class CloudEstimateError(Exception):
    """Estimating the pose of cloud ``cloud`` ('A' or 'B') failed; ``__cause__`` says why."""

    def __init__(self, cloud: str, cause: Exception) -> None:
        self.cloud = cloud
        super().__init__(f"cloud {cloud}: {cause}")


@dataclass(frozen=True)
class AlignOptions:
    """Knobs of ``align_clouds``. Distances are fractions of B's RMS radius about its centroid
    (``itnet.preprocess``), so they work in any unit."""

    starts: int = 4  # IT-Net runs per cloud, from turns of 360/starts degrees about z
    points: int = 192  # points IT-Net sees per run: a random subset each
    iterations: int | None = None  # per run; None: 6 with several starts, the model's with one
    symmetry: str = "yaw90"  # a name in itnet.symmetry.SYMMETRY_NAMES
    refine: bool = False
    candidates: int = 12  # distinct hypotheses kept (and refined, with refine) after ranking
    finalists: int = 4  # with refine: candidates that get ICP's fine stage, the best after its
    # coarse one (all of them when finalists >= candidates)
    coarse_points: int | None = 200  # points of A in ICP's coarse stage (None: all)
    distinct_deg: float = 30.0  # hypotheses closer than this (and distinct_shift) count as one
    distinct_shift: float = 0.3
    icp_distance: float = 0.1  # ICP's final correspondence cut-off (the first stage: twice it)
    icp_tolerance: float = 1e-4  # ICP stops once fitness and RMSE change less than this
    inlier_distance: float = 0.05  # the final score's inlier distance
    rank_points: int = 32  # points of each cloud the loose ranking measures
    score_points: int = 300  # points of each cloud the final score measures
    voxel: float | None = None  # ICP downsampling; None: 0.05 above 20,000 points, else none
    seed: int = 0

    def run_iterations(self) -> int | None:
        """IT-Net iterations per run (None: the estimator's own default)."""
        if self.iterations is not None:
            return self.iterations
        return SHORT_RUN if self.starts > 1 else None


TREE_POINTS = 20_000  # points of each cloud in the scoring KD-trees (a random subset beyond)

# Tilting every second start: on 600 tuning pairs (seeds 7 and 11) 78.7% aligned against 77.3%
# with turns about z alone (docs/align.md).
START_TILT_DEG = 20.0

# With several starts, shorter runs: 4 starts x 6 iterations aligned more pairs than 2 x 10 or
# 1 x 10 in about the same time (docs/align.md).
SHORT_RUN = 6


@dataclass
class Alignment:
    """The answer: T_b_from_a (4x4, moves A onto B, B's units) and how it was reached."""

    T_b_from_a: NDArray[np.float64]
    pose_a: PoseEstimate  # IT-Net's first run on A (from the identity)
    pose_b: PoseEstimate
    hypotheses: list[Hypothesis]  # the candidates, scored (and refined, with refine)
    chosen: int
    confidence: dict[str, float]
    timings_ms: dict[str, float] = field(default_factory=dict)  # itnet, rank, refine, score, total
    iterations: int = 0  # IT-Net steps over every run (both clouds, all starts)
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


def starting_turns(count: int, tilt_deg: float = START_TILT_DEG) -> NDArray[np.float64]:
    """Alignment's ``count`` starting rotations (count, 3, 3): ``geometry.viewing_axis_turns``
    with every second start tilted by ``tilt_deg`` (measured to help alignment, above)."""
    return viewing_axis_turns(count, tilt_deg)


def _runs(
    estimate: PoseEstimator, points: NDArray, options: AlignOptions, name: str, up: NDArray | None
) -> list:
    """IT-Net from every starting turn (about ``up`` where it is given), each run on its own
    subset of ``options.points``."""
    turns = starting_turns(options.starts) if up is None else turns_about(up, options.starts)
    try:
        runs = estimate(points, turns, options.run_iterations(), options.points, up=up)
    except Exception as err:  # the estimator's own errors, labelled with the cloud they concern
        raise CloudEstimateError(name, err) from err
    if len(runs) != options.starts:
        raise CloudEstimateError(
            name, RuntimeError(f"{len(runs)} poses for {options.starts} starts")
        )
    return runs


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

    ``estimate`` maps a cloud (K, 3) and starting rotations to one IT-Net PoseEstimate per
    start (``PoseEstimator``); what it raises comes back as CloudEstimateError (``__cause__``:
    the original). Raises ``itnet.alignment.refine.RefineUnavailable``
    when refinement needs open3d and it is absent.
    """
    if options.starts < 1 or options.candidates < 1 or options.points < 3:
        raise ValueError("starts and candidates must be >= 1, points >= 3")
    start = time.perf_counter()
    ups = [None if up is None else unit_up(up) for up in (up_a, up_b)]
    a = np.asarray(points_a, dtype=np.float64)
    b = np.asarray(points_b, dtype=np.float64)
    runs_a = _runs(estimate, a, options, "A", ups[0])
    runs_b = _runs(estimate, b, options, "B", ups[1])
    t_itnet = time.perf_counter()

    scale = estimate_normalization(b).scale
    # KD-trees on at most TREE_POINTS of each cloud: a 100,000-point scan scores the same on a
    # fifth of its points, and its tree builds in a fraction of the time.
    cloud_a = Cloud(sample(a, TREE_POINTS, options.seed))
    cloud_b = Cloud(sample(b, TREE_POINTS, options.seed + 1))
    every = build_hypotheses(
        [r.T_canonical_from_input for r in runs_a], [r.T_canonical_from_input for r in runs_b],
        symmetry_rotations(options.symmetry),
    )  # fmt: skip
    # Rank at ICP's first-stage distance, where an unrefined estimate still lands on B.
    loose, _ = overlap(np.array([h.T_b_from_a for h in every]), cloud_a, cloud_b,
                       2 * options.icp_distance * scale, options.rank_points, options.seed)  # fmt: skip
    for h, fit in zip(every, loose):
        h.loose_fitness = float(fit)
    keep = distinct(every, loose, options.candidates, scale, options.distinct_deg,
                    options.distinct_shift)  # fmt: skip
    hypotheses = [every[k] for k in keep]
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
        finalists = set(np.argsort(-fit, kind="stable")[: options.finalists].tolist())
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
    # Unrefined hypotheses are each a few degrees off: the tight score cannot rank them, so
    # without ICP the loose ranking decides (the candidates are in its order).
    chosen = choose(hypotheses) if options.refine else 0
    done = time.perf_counter()
    return Alignment(
        T_b_from_a=hypotheses[chosen].T_b_from_a,
        pose_a=runs_a[0],
        pose_b=runs_b[0],
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
        iterations=sum(r.iterations for r in runs_a + runs_b),  # one batched step: B steps
        considered=len(every),
        scale=scale,
        inlier_distance=options.inlier_distance * scale,
        icp_distance=options.icp_distance * scale if options.refine else 0.0,
    )
