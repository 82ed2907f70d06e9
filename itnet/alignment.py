"""Align cloud A onto cloud B: two canonical poses, hypotheses, optional ICP, the chosen one.

The steps (the policy is explained in ``itnet.align``)::

    pose_a, pose_b = estimate(A), estimate(B)          # IT-Net, in-process or via the service
    hypotheses     = itnet, itnet composed with the category's symmetries, subset estimates
    each           = ICP(hypothesis)                   # only with refine=True
    chosen         = the IT-Net one unless another fits the geometry clearly better
    confidence     = from the chosen fit and its margin over rivals

The pose estimator is passed in (a callable), so this module does no I/O and loads no model: the
CLI gives it an in-process ``AnytimeRun`` or an HTTP client, the benchmark the same.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.align import (
    Hypothesis,
    build_hypotheses,
    choose,
    confidence,
    overlap_score,
    symmetry_rotations,
)
from itnet.geometry import rotation_angle_deg
from itnet.preprocess import estimate_normalization


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


PoseEstimator = Callable[[NDArray[np.float64]], PoseEstimate]


class CloudEstimateError(Exception):
    """Estimating the pose of cloud ``cloud`` ('A' or 'B') failed; ``__cause__`` says why."""

    def __init__(self, cloud: str, cause: Exception) -> None:
        self.cloud = cloud
        super().__init__(f"cloud {cloud}: {cause}")


@dataclass(frozen=True)
class AlignOptions:
    """Knobs of ``align_clouds``. Distances are fractions of B's RMS radius about its centroid
    (``itnet.preprocess``), so they work in any unit."""

    samples: int = 1  # IT-Net runs per cloud: the whole cloud, then random subsets
    subset_fraction: float = 0.8
    symmetry: str = "yaw90"  # a name in itnet.align.SYMMETRIES
    refine: bool = False
    icp_distance: float = 0.1  # ICP's final correspondence cut-off (the first stage: twice it)
    inlier_distance: float = 0.05  # the overlap score's inlier distance
    switch_margin: float = 0.02  # fitness a rival needs above the IT-Net estimate to replace it
    score_points: int = 400  # points of each cloud scored against (up to 5x as many of) the other
    rivals: int | None = None  # with refine: ICP the IT-Net estimate and only this many rivals,
    # those that fit best before ICP (at ICP's first-stage distance); None: every hypothesis
    voxel: float | None = None  # ICP downsampling; None: 0.05 above 20,000 points, else none
    seed: int = 0


@dataclass
class Alignment:
    """The answer: T_b_from_a (4x4, moves A onto B, B's units) and how it was reached."""

    T_b_from_a: NDArray[np.float64]
    pose_a: PoseEstimate  # IT-Net on the whole of A
    pose_b: PoseEstimate
    hypotheses: list[Hypothesis]
    chosen: int
    confidence: dict[str, float]
    timings_ms: dict[str, float] = field(default_factory=dict)  # itnet, refine, score, total
    iterations: int = 0  # IT-Net steps over every run (both clouds, all samples)
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
            "inlier_distance": float(f"{self.inlier_distance:.5g}"),
            "icp_distance": float(f"{self.icp_distance:.5g}"),
            "refined": self.hypotheses[self.chosen].initial is not None,
            "T_canonical_from_a": self.pose_a.to_dict(),
            "T_canonical_from_b": self.pose_b.to_dict(),
            "hypotheses": [h.to_dict() for h in self.hypotheses],
        }


def _subsets(points: NDArray, count: int, fraction: float, rng: np.random.Generator) -> list:
    """The whole cloud, then ``count - 1`` random subsets of ``fraction`` of its points."""
    size = max(1, round(fraction * len(points)))
    subsets = [points[rng.choice(len(points), size, replace=False)] for _ in range(count - 1)]
    return [points, *subsets]


def _estimate_all(estimate: PoseEstimator, clouds: list, name: str) -> list[PoseEstimate]:
    try:
        return [estimate(x) for x in clouds]
    except Exception as err:  # the estimator's own errors, labelled with the cloud they concern
        raise CloudEstimateError(name, err) from err


def _best_rivals(
    hypotheses: list[Hypothesis],
    sub_a: NDArray,
    sub_b: NDArray,
    distance: float,
    rivals: int,
    points: int,
) -> list[Hypothesis]:
    """The IT-Net estimate (first) and the ``rivals`` other hypotheses that fit best as they are,
    at ``distance`` (ICP's first-stage cut-off, where an unrefined estimate still lands)."""
    fit = [overlap_score(sub_a, sub_b, h.T_b_from_a, distance, points)[0] for h in hypotheses[1:]]
    keep = sorted(np.argsort(fit)[::-1][:rivals] + 1)
    return [hypotheses[0], *(hypotheses[i] for i in keep)]


def align_clouds(
    points_a: ArrayLike, points_b: ArrayLike, estimate: PoseEstimator, options: AlignOptions
) -> Alignment:
    """Cloud A (N, 3) and B (M, 3), each in its own frame and unit-consistent -> Alignment.

    ``estimate`` maps a cloud (K, 3) to its IT-Net PoseEstimate; what it raises comes back as
    CloudEstimateError (``__cause__``: the original). Raises ``itnet.refine.RefineUnavailable``
    when refinement needs open3d and it is absent.
    """
    start = time.perf_counter()
    a = np.asarray(points_a, dtype=np.float64)
    b = np.asarray(points_b, dtype=np.float64)
    rng = np.random.default_rng(options.seed)
    runs_a = _estimate_all(
        estimate, _subsets(a, options.samples, options.subset_fraction, rng), "A"
    )
    runs_b = _estimate_all(
        estimate, _subsets(b, options.samples, options.subset_fraction, rng), "B"
    )
    t_itnet = time.perf_counter()

    scale = estimate_normalization(b).scale
    inlier = options.inlier_distance * scale
    hypotheses = build_hypotheses(
        [r.T_canonical_from_input for r in runs_a], [r.T_canonical_from_input for r in runs_b],
        symmetry_rotations(options.symmetry), scale,
    )  # fmt: skip
    # Score every hypothesis the same way, on seeded subsets of both clouds.
    cap = 5 * options.score_points
    sub_a = a[rng.choice(len(a), cap, replace=False)] if len(a) > cap else a
    sub_b = b[rng.choice(len(b), cap, replace=False)] if len(b) > cap else b
    if options.refine and options.rivals is not None and len(hypotheses) > 1 + options.rivals:
        hypotheses = _best_rivals(hypotheses, sub_a, sub_b, 2 * options.icp_distance * scale,
                                  options.rivals, options.score_points // 2)  # fmt: skip
    if options.refine:
        from itnet.refine import IcpRefiner

        voxel = options.voxel
        if voxel is None:
            voxel = 0.05 if max(len(a), len(b)) > 20_000 else 0.0
        refiner = IcpRefiner(a, b, options.icp_distance * scale, voxel=voxel * scale)
        for h in hypotheses:
            refined = refiner.refine(h.T_b_from_a)
            h.initial, h.T_b_from_a = h.T_b_from_a, refined.T_b_from_a
            h.icp = {"fitness": round(refined.fitness, 4), "rmse": float(f"{refined.rmse:.5g}")}
            h.source += "+icp"
    t_refine = time.perf_counter()

    for h in hypotheses:
        h.fitness, h.rmse = overlap_score(sub_a, sub_b, h.T_b_from_a, inlier, options.score_points)
    # Unrefined hypotheses are each a few degrees off: the tight score cannot rank them, so
    # without ICP they only inform the confidence (a rival that fits as well lowers it).
    chosen = choose(hypotheses, options.switch_margin) if options.refine else 0
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
            "refine": (t_refine - t_itnet) * 1e3,
            "score": (done - t_refine) * 1e3,
            "total": (done - start) * 1e3,
        },
        iterations=sum(r.iterations for r in runs_a + runs_b),
        inlier_distance=inlier,
        icp_distance=options.icp_distance * scale if options.refine else 0.0,
    )
