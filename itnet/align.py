"""Relative alignment of two clouds from their canonical poses: hypotheses, scores, confidence.

Pure numpy: no files, no network, no model. Frames (SPEC.md):

* ``T_canonical_from_a`` (4x4) maps a point of cloud A into the category's canonical frame;
  likewise for B. Both come from IT-Net (``itnet.service.engine.AnytimeRun``).
* ``T_b_from_a = inv(T_canonical_from_b) · T_canonical_from_a`` moves cloud A onto cloud B.

Why hypotheses. A category-level pose can be wrong in structured ways: a chair seen from its
side looks much the same turned 180 degrees about its up axis (+y), and a sparse view gives a
different answer on a different subset of its points. So the alignment considers

1. the IT-Net estimate ``inv(T_cb) · T_ca``;
2. the same estimate with A's canonical pose composed with each likely symmetry ``S`` of the
   category, ``inv(T_cb) · S · T_ca`` (what it is if exactly one of the two poses is off by S);
3. optionally, estimates from random subsets of both clouds (``samples`` > 1);

refines each with ICP when asked (``itnet.refine``), scores each by how well the moved A lies on
B (``overlap_score``), and keeps the IT-Net estimate unless another hypothesis explains the
geometry clearly better (``switch_margin``), because with little overlap the geometric score is
the weaker witness. ``confidence`` says how much the answer can be trusted (see its docstring).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import (
    apply_rigid,
    axis_angle_to_matrix,
    invert_rigid,
    rotation_error_deg,
)

# Rotations about the canonical origin under which a category often looks alike (+y is up).
SYMMETRIES: dict[str, tuple[float, ...]] = {
    "none": (),
    "yaw180": (180.0,),
    "yaw90": (90.0, 180.0, 270.0),
}
CATEGORY_SYMMETRY = {"chair": "yaw90", "sofa": "yaw180", "bed": "yaw180", "toilet": "yaw180",
                     "monitor": "yaw180", "bathtub": "yaw180", "table": "yaw90",
                     "desk": "yaw180", "night_stand": "yaw90", "dresser": "yaw90"}  # fmt: skip


def relative_pose(canonical_from_a: ArrayLike, canonical_from_b: ArrayLike) -> NDArray[np.float64]:
    """T_canonical_from_a, T_canonical_from_b (...x4x4) -> T_b_from_a (...x4x4)."""
    return np.asarray(invert_rigid(canonical_from_b) @ np.asarray(canonical_from_a, np.float64))


def symmetry_rotations(name: str) -> NDArray[np.float64]:
    """Named symmetry set -> its rotations (Sx4x4, canonical frame), without the identity."""
    if name not in SYMMETRIES:
        raise ValueError(f"unknown symmetry {name!r} (known: {', '.join(SYMMETRIES)})")
    out = np.tile(np.eye(4), (len(SYMMETRIES[name]), 1, 1))
    for i, angle in enumerate(SYMMETRIES[name]):
        out[i, :3, :3] = axis_angle_to_matrix([0.0, 1.0, 0.0], np.radians(angle))
    return out


def category_symmetry(category: str) -> str:
    """The symmetry set assumed for a category (``yaw180`` when unknown). A chair's seat is
    nearly square, so a partial view of it is often explained as well by a quarter turn."""
    return CATEGORY_SYMMETRY.get(category, "yaw180")


@dataclass
class Hypothesis:
    """A candidate T_b_from_a (4x4, B's units) and, once scored, how well it fits the geometry."""

    T_b_from_a: NDArray[np.float64]
    source: str  # "itnet", "itnet+yaw180", "sample 2", with "+icp" once refined
    fitness: float = float("nan")  # symmetric share of points within the inlier distance
    rmse: float = float("nan")  # RMS distance of those inliers, B's units
    initial: NDArray[np.float64] | None = field(default=None, repr=False)  # before refinement
    icp: dict[str, float] | None = None  # open3d's fitness and inlier RMSE of the last ICP stage

    def to_dict(self) -> dict:
        rmse = float(f"{self.rmse:.5g}")
        out = {"source": self.source, "fitness": round(self.fitness, 4), "rmse": rmse,
               "T_b_from_a": self.T_b_from_a.tolist()}  # fmt: skip
        return out if self.icp is None else {**out, "icp": self.icp}


def build_hypotheses(
    poses_a: ArrayLike, poses_b: ArrayLike, symmetries: ArrayLike, scale: float
) -> list[Hypothesis]:
    """Candidate alignments from IT-Net poses.

    poses_a, poses_b: (K, 4, 4) T_canonical_from_a / _b, row 0 from the whole cloud and rows
    1.. from random subsets; symmetries: (S, 4, 4) canonical-frame rotations (no identity);
    scale: a length in B's units (its RMS radius) for telling near-duplicates apart.
    Returns the IT-Net estimate first, then its symmetric variants, then the subset estimates
    that differ from every earlier hypothesis by more than 5 degrees or 0.05 scale.
    """
    pa, pb = np.asarray(poses_a, dtype=np.float64), np.asarray(poses_b, dtype=np.float64)
    main = relative_pose(pa[0], pb[0])
    found = [Hypothesis(main, "itnet")]
    for sym in np.asarray(symmetries, dtype=np.float64):
        yaw = round(float(np.degrees(np.arctan2(sym[0, 2], sym[0, 0])))) % 360  # about +y
        name = f"itnet+yaw{yaw}"
        found.append(Hypothesis(invert_rigid(pb[0]) @ sym @ pa[0], name))
    for i in range(1, min(len(pa), len(pb))):
        candidate = relative_pose(pa[i], pb[i])
        if all(not same_alignment(candidate, h.T_b_from_a, scale) for h in found):
            found.append(Hypothesis(candidate, f"sample {i}"))
    return found


def same_alignment(
    t1: ArrayLike, t2: ArrayLike, scale: float, max_deg: float = 5.0, max_shift: float = 0.05
) -> bool:
    """Whether two T_b_from_a (4x4) agree within ``max_deg`` and ``max_shift`` x scale (B's units,
    measured as the distance between the two translations)."""
    a, b = np.asarray(t1), np.asarray(t2)
    angle = float(rotation_error_deg(a[:3, :3], b[:3, :3]))
    return angle < max_deg and float(np.linalg.norm(a[:3, 3] - b[:3, 3])) < max_shift * scale


def nearest_distances(source: ArrayLike, target: ArrayLike, chunk: int = 256) -> NDArray:
    """For each source point (N, 3), the distance to its nearest target point (M, 3): (N,).

    Brute force in chunks (clouds are subsampled to a few hundred points for scoring), as
    |s|^2 + min_j (|t_j|^2 - 2 s.t_j) about the target's centroid, which keeps the cancellation
    small for clouds far from their frame's origin. The dot products are three elementwise
    passes, not a BLAS call: a threaded BLAS is slow on matrices this thin, and worse on a
    busy machine."""
    t = np.asarray(target, dtype=np.float64)
    centre = t.mean(axis=0)
    t = t - centre
    s = np.asarray(source, dtype=np.float64) - centre
    t_sq = np.sum(t * t, axis=1)
    out = np.empty(len(s))
    for start in range(0, len(s), chunk):
        b = s[start : start + chunk]
        dot = b[:, 0:1] * t[:, 0] + b[:, 1:2] * t[:, 1] + b[:, 2:3] * t[:, 2]
        d2 = (t_sq - 2.0 * dot).min(axis=1) + np.sum(b * b, axis=1)
        out[start : start + chunk] = np.sqrt(np.maximum(d2, 0.0))
    return out


def overlap_score(
    points_a: ArrayLike,
    points_b: ArrayLike,
    b_from_a: ArrayLike,
    inlier_distance: float,
    sources: int | None = None,
) -> tuple[float, float]:
    """How well A (N, 3), moved by T_b_from_a, lies on B (M, 3) -> (fitness, rmse).

    fitness: mean of the share of moved-A points within ``inlier_distance`` of B and the share
    of B points within it of moved A (symmetric, in [0, 1]); rmse: RMS distance of those
    inlier pairs, B's units (``inf`` when there are none). ``sources``: measure the shares on
    that many points of each side (a fixed random subset) against all points of the other."""
    moved = apply_rigid(np.asarray(b_from_a, dtype=np.float64), points_a)
    b = np.asarray(points_b, dtype=np.float64)
    d_ab = nearest_distances(_subset(moved, sources), b)
    d_ba = nearest_distances(_subset(b, sources), moved)
    near_ab, near_ba = d_ab < inlier_distance, d_ba < inlier_distance
    inliers = np.concatenate([d_ab[near_ab], d_ba[near_ba]])
    fitness = 0.5 * (float(np.mean(near_ab)) + float(np.mean(near_ba)))
    rmse = float(np.sqrt(np.mean(inliers**2))) if len(inliers) else float("inf")
    return fitness, rmse


def _subset(points: NDArray, count: int | None) -> NDArray:
    if count is None or len(points) <= count:
        return points
    return points[np.random.default_rng(0).choice(len(points), count, replace=False)]


def choose(hypotheses: list[Hypothesis], switch_margin: float) -> int:
    """Index of the hypothesis to report: the best by fitness (then rmse), but the first one (the
    IT-Net estimate) unless the best beats it by more than ``switch_margin`` in fitness."""
    best = max(range(len(hypotheses)), key=lambda i: (hypotheses[i].fitness, -hypotheses[i].rmse))
    if hypotheses[best].fitness - hypotheses[0].fitness > switch_margin:
        return best
    return 0


def confidence(hypotheses: list[Hypothesis], chosen: int, scale: float) -> dict[str, float]:
    """How far the chosen alignment can be trusted, in [0, 1], with its two parts.

    * ``fitness``: the chosen hypothesis's symmetric overlap (0 = A lands nowhere near B);
    * ``margin``: its fitness minus that of the best rival, a hypothesis that disagrees with it by
      more than 10 degrees or 0.1 scale (the whole fitness when there is no rival): a symmetric
      object or a featureless view makes rivals fit as well, and the margin falls to 0;
    * ``confidence = sqrt(clip(fitness / 0.4) · clip(margin / 0.2))``: 1 when A lands on B
      (0.4 of the points within the inlier distance is a good fit for two partial views) and
      no alternative comes close. Without ICP the fit is measured on the raw IT-Net estimate,
      whose few degrees of error already push points past a tight inlier distance: expect a
      low confidence there, which says "not verified", not "wrong".
    """
    best = hypotheses[chosen]
    rivals = [h.fitness for h in hypotheses
              if not same_alignment(h.T_b_from_a, best.T_b_from_a, scale, 10.0, 0.1)]  # fmt: skip
    margin = best.fitness - max(rivals) if rivals else best.fitness
    value = float(np.sqrt(np.clip(best.fitness / 0.4, 0, 1) * np.clip(margin / 0.2, 0, 1)))
    return {"confidence": round(value, 4), "fitness": round(best.fitness, 4),
            "margin": round(float(margin), 4)}  # fmt: skip
