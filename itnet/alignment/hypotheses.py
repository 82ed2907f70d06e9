"""Relative alignment of two clouds from their canonical poses: the hypotheses.

Pure numpy: no files, no network, no model. Frames (SPEC.md):

* ``T_canonical_from_a`` (4x4) maps a point of cloud A into the category's canonical frame;
  likewise for B. Both come from IT-Net (``itnet.pose.loop.AnytimeRun``).
* ``T_b_from_a = inv(T_canonical_from_b) · T_canonical_from_a`` moves cloud A onto cloud B.

Why hypotheses. A category-level pose can be wrong in structured ways: a chair seen from its
side looks much the same turned 90 or 180 degrees about its up axis (+y), and a sparse view can
send IT-Net to a different answer from a different start. So the alignment considers, for IT-Net
runs ``i`` on A and ``j`` on B (each from its own starting rotation, ``itnet.alignment.pipeline``) and
each likely symmetry ``S`` of the category (the identity first),

    inv(T_cb[j]) · S · T_ca[i]          (what T_b_from_a is if A's pose i is off by S)

where the composed pose of the two served poses is in doubt: it ranks them by how well the moved
A lies on B at a loose distance, keeps the best few that are distinct (``distinct``), refines
those with ICP when asked (``itnet.alignment.refine``), and judges each by the evidence of
``itnet.alignment.choice``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import axis_angle_to_matrix, invert_rigid, rotation_error_deg
from itnet.symmetry import symmetry_group

# Hypothesis sets are the symmetry groups of itnet.symmetry ('none', 'yaw180', 'yaw90', 'yaw');
# the continuous 'yaw' is tried every 30 degrees.
HYPOTHESIS_YAW_SAMPLES = 12


def relative_pose(canonical_from_a: ArrayLike, canonical_from_b: ArrayLike) -> NDArray[np.float64]:
    """T_canonical_from_a, T_canonical_from_b (...x4x4) -> T_b_from_a (...x4x4)."""
    return np.asarray(invert_rigid(canonical_from_b) @ np.asarray(canonical_from_a, np.float64))


def symmetry_rotations(name: str) -> NDArray[np.float64]:
    """Named symmetry set -> its rotations (Sx4x4, canonical frame), without the identity."""
    group = symmetry_group(name, HYPOTHESIS_YAW_SAMPLES)[1:]  # raises for an unknown name
    out = np.tile(np.eye(4), (len(group), 1, 1))
    out[:, :3, :3] = group
    return out


def rival_turns(category: str, declared: str = "none") -> str:
    """The symmetric turns an alignment tries as rivals for a category whose model card declares
    the symmetry ``declared`` (``itnet.symmetry``): the declared group where it is wider than
    the turns the category's views are often mistaken by (``Category.confusions``, in
    ``itnet.model.categories``; ``yaw180`` for a category it does not know)."""
    from itnet.model.categories import MODELNET10

    if declared in ("yaw", "yaw90"):
        return declared
    known = MODELNET10.get(category)
    return "yaw180" if known is None else known.confusions


@dataclass
class Hypothesis:
    """A candidate T_b_from_a (4x4, B's units) and, once scored, how well it fits the geometry."""

    T_b_from_a: NDArray[np.float64]
    source: str  # "itnet" (the served poses), "itnet+yaw180", "itnet a1 b0+yaw90" (A's run 1,
    # B's served pose, a quarter turn), with "+icp" once refined
    fitness: float = float("nan")  # symmetric share of points within the inlier distance
    rmse: float = float("nan")  # RMS distance of those inliers, B's units
    loose_fitness: float = float("nan")  # the share at the ranking distance, before refinement
    initial: NDArray[np.float64] | None = field(default=None, repr=False)  # before refinement
    icp: dict[str, float] | None = None  # open3d's fitness and inlier RMSE of the last ICP stage
    served: bool = False  # built from the two served poses (no other run's)
    turned: bool = False  # a symmetry turn applied
    evidence: NDArray[np.float64] | None = field(default=None, repr=False)  # choice.FEATURES
    probability: float = float("nan")  # calibrated, that it is right (itnet.alignment.choice)

    def to_dict(self) -> dict:
        rmse = float(f"{self.rmse:.5g}")
        out = {"source": self.source, "probability": round(self.probability, 4),
               "fitness": round(self.fitness, 4), "rmse": rmse,
               "loose_fitness": round(self.loose_fitness, 4),
               "T_b_from_a": self.T_b_from_a.tolist()}  # fmt: skip
        return out if self.icp is None else {**out, "icp": self.icp}


def build_hypotheses(
    poses_a: ArrayLike, poses_b: ArrayLike, symmetries: ArrayLike
) -> list[Hypothesis]:
    """Every candidate alignment from IT-Net poses: for each pose i of A, pose j of B and
    symmetry S (the identity first), ``inv(T_cb[j]) · S · T_ca[i]``.

    poses_a: (Ra, 4, 4) T_canonical_from_a: the served pose first, then each run's own
    (``PoseEstimate.candidates``); poses_b: (Rb, 4, 4) likewise;
    symmetries: (S, 4, 4) canonical-frame rotations (no identity). Returns Ra·Rb·(S+1)
    hypotheses, the two served poses without a symmetry first (named "itnet"; the others name
    their poses when not the served ones, e.g. "itnet a1 b0+yaw90").
    """
    pa, pb = np.asarray(poses_a, dtype=np.float64), np.asarray(poses_b, dtype=np.float64)
    syms = np.concatenate([np.eye(4)[None], np.asarray(symmetries, dtype=np.float64)])
    names = [""]
    for sym in syms[1:]:
        yaw = round(float(np.degrees(np.arctan2(sym[0, 2], sym[0, 0])))) % 360  # about +y
        names.append(f"+yaw{yaw}")
    # (Ra, Rb, S+1, 4, 4): every run of A, every run of B, every symmetry, in one product.
    poses = invert_rigid(pb)[None, :, None] @ syms[None, None] @ pa[:, None, None]
    found = []
    for i in range(len(pa)):
        for j in range(len(pb)):
            runs = "" if i == j == 0 else f" a{i} b{j}"
            for k, turn in enumerate(names):
                found.append(
                    Hypothesis(
                        poses[i, j, k], f"itnet{runs}{turn}", served=i == j == 0, turned=k > 0
                    )
                )
    return found


def spread_order(count: int) -> list[int]:
    """The steps 0..count-1 of a circle in the order that keeps each new one farthest from
    those before it (ties: the lowest): 0, count/2, count/4, 3 count/4, ..."""
    order = [0] if count else []
    rest = list(range(1, count))
    while rest:
        gaps = [min(min(abs(k - j), count - abs(k - j)) for j in order) for k in rest]
        order.append(rest.pop(int(np.argmax(gaps))))
    return order


def yaw_sweep(
    composed: ArrayLike, up_b: ArrayLike, centroid_a: ArrayLike, centroid_b: ArrayLike, turns: int
) -> list[Hypothesis]:
    """Starts that do not lean on the networks' yaw, for two clouds whose ups are known: the
    composed pose's rotation (4x4; it already carries A's up onto B's) turned about B's up
    (3,, unit) by each of ``turns`` equal steps, each shifted to move A's centroid (3,) onto
    B's -> ``turns`` hypotheses named "sweep yaw{degrees}", marked turned, in an order whose
    every prefix spreads evenly round the circle (0, 180, 90, 270, ... degrees), so a sweep cut
    short by its budget still looks all round. A view seen from another side is often one the
    networks turn wrongly by a few tens of degrees, which no symmetry turn repairs; one of these
    starts lies within ICP's reach."""
    rotation = np.asarray(composed, dtype=np.float64)[:3, :3]
    ca, cb = np.asarray(centroid_a, np.float64), np.asarray(centroid_b, np.float64)
    steps = np.array(spread_order(turns))
    angles = 2.0 * np.pi * steps / turns
    found = []
    for angle, turn in zip(angles, axis_angle_to_matrix(up_b, angles).reshape(-1, 3, 3)):
        pose = np.eye(4)
        pose[:3, :3] = turn @ rotation
        pose[:3, 3] = cb - pose[:3, :3] @ ca
        found.append(Hypothesis(pose, f"sweep yaw{round(np.degrees(angle))}", turned=True))
    return found


def distinct(
    hypotheses: list[Hypothesis],
    scores: ArrayLike,
    count: int,
    scale: float,
    max_deg: float = 30.0,
    max_shift: float = 0.3,
) -> list[int]:
    """Indices of up to ``count`` hypotheses, best ``scores`` (H,) first, skipping any that is
    the same alignment as one already kept (within ``max_deg`` and ``max_shift`` x scale): many
    hypotheses are near-copies of one another, and refining copies wastes the ICP budget."""
    poses = np.array([h.T_b_from_a for h in hypotheses], dtype=np.float64)
    rot, shift = poses[:, :3, :3], poses[:, :3, 3]
    # Pairwise (H, H): the angle between the rotations, the distance between the translations.
    close = rotation_error_deg(rot[:, None], rot[None]) < max_deg
    close &= np.linalg.norm(shift[:, None] - shift[None], axis=-1) < max_shift * scale
    kept: list[int] = []
    for k in np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable"):
        if not close[k, kept].any():
            kept.append(int(k))
            if len(kept) == count:
                break
    return kept


def same_alignment(
    t1: ArrayLike, t2: ArrayLike, scale: float, max_deg: float = 5.0, max_shift: float = 0.05
) -> bool:
    """Whether two T_b_from_a (4x4) agree within ``max_deg`` and ``max_shift`` x scale (B's units,
    measured as the distance between the two translations)."""
    a, b = np.asarray(t1), np.asarray(t2)
    angle = float(rotation_error_deg(a[:3, :3], b[:3, :3]))
    return angle < max_deg and float(np.linalg.norm(a[:3, 3] - b[:3, 3])) < max_shift * scale
