"""Align cloud A onto cloud B: both clouds' served poses, the composed pose, rivals where it is in
doubt, the likeliest.

The steps::

    pose_a, pose_b = estimate(A), estimate(B)   # admitted as one request, run in turn
    composed = inv(T_b) · T_a                   # the prior: the two served poses composed
    composed+icp = ICP(composed)                # with refine=True
    p = probability(evidence)                   # ``itnet.alignment.choice``: calibrated
    if max p < sure or a rival lands            # in doubt (both held upright: always): the rivals
            clearly more of A on B (loosely):
        hypotheses = inv(T_b[j]) · S · T_a[i]   # every run of A and of B, every symmetry turn
        rivals = the distinct ones that overlap best, each refined by ICP
    chosen = the likeliest (the composed pose unless a rival is more likely right; refined by
             ICP where that keeps it within 10 degrees and 0.1 radii: the same alignment)

Why the served poses. A category-level pose needs no overlap between the two views, which
correspondence-based registration does; the pose pipeline's finishing stages make each pose as
good as the category's model can give it, and composing two such poses is the alignment. A rival
replaces it only where the evidence says it is more likely right: how well the clouds agree
after the move, how much they overlap at all, and how many of the networks' runs back it.

``options.budget_ms`` is the whole alignment's: the poses get ``POSE_SHARE`` of it, and the
rivals are scored only where the time left holds them.

Where the caller knows which way is up in a cloud (``up_a``, ``up_b``: gravity from an IMU, a
floor's normal), its pose is estimated held upright (``itnet.upright``). Models whose card
requires up (the night stand) align only this way.

The pose estimator is passed in (a callable; ``itnet.alignment.estimators`` has the in-process
one that every path uses, ``POST /v1/align`` included), so this module does no I/O and loads no
model, and the tests give it estimators that know the truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.alignment.choice import choose, feature_row, icp_move, probability, support
from itnet.alignment.hypotheses import (
    Hypothesis,
    build_hypotheses,
    distinct,
    same_alignment,
    symmetry_rotations,
    yaw_sweep,
)
from itnet.alignment.overlap import Cloud, overlap, sample
from itnet.geometry import rotation_angle_deg
from itnet.preprocess import estimate_normalization
from itnet.upright import unit_up

if TYPE_CHECKING:
    from itnet.alignment.refine import RefineResult


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


# The composed pose at or above this calibrated probability is answered without scoring rivals
# (docs/align.md: chosen on validation pairs of every generator).
SURE = 0.9
POSE_SHARE = 0.75  # of the alignment's budget, for the two clouds' poses
SWEEP_LEAST = 4  # turns about up the budget must hold for a sweep to start
SWEEP_MARGIN = 0.05  # of the budget, left when the sweep ends (its ICP's time varies)
DOUBT_LOOSE = 0.1  # a rival landing this much more of A on B (loosely) puts the composed in doubt


@dataclass(frozen=True)
class AlignOptions:
    """Knobs of ``align_clouds``. Distances are fractions of B's RMS radius about its centroid
    (``itnet.preprocess``), so they work in any unit."""

    symmetry: str = "yaw90"  # a name in itnet.symmetry.SYMMETRY_NAMES
    refine: bool = False
    budget_ms: float | None = None  # the whole alignment's (None: no limit on the rivals)
    sure: float = SURE  # the composed pose this likely right is answered as it is (> 1: the
    # rivals are always scored)
    rivals: bool = True  # False: the composed pose (and its ICP) only
    candidates: int = 6  # distinct rivals kept after ranking (and refined, with refine)
    finalists: int = 3  # with refine: rivals that get ICP's fine stage, the best after its
    # coarse one (all of them when finalists >= candidates)
    sweep: int = 24  # with refine, rivals and both ups: turns about up tried from the composed
    # pose, each refined by ICP's coarse stage, the best ``finalists`` by its fine one (0: none)
    coarse_points: int | None = 200  # points of A in ICP's coarse stage (None: all)
    distinct_deg: float = 30.0  # hypotheses closer than this (and distinct_shift) count as one
    distinct_shift: float = 0.3
    icp_distance: float = 0.1  # ICP's final correspondence cut-off (the first stage: twice it)
    icp_tolerance: float = 1e-4  # ICP stops once fitness and RMSE change less than this
    inlier_distance: float = 0.05  # the fitness's inlier distance
    rank_points: int = 32  # points of each cloud the rivals' ranking measures
    score_points: int = 300  # points of each cloud the fitness measures
    voxel: float | None = None  # ICP downsampling; None: 0.05 above 20,000 points, else none
    seed: int = 0


TREE_POINTS = 20_000  # points of each cloud in the scoring KD-trees (a random subset beyond)


@dataclass
class Alignment:
    """The answer: T_b_from_a (4x4, moves A onto B, B's units) and how it was reached."""

    T_b_from_a: NDArray[np.float64]
    pose_a: PoseEstimate  # A's served pose
    pose_b: PoseEstimate
    hypotheses: list[Hypothesis]  # the candidates judged: the composed pose first
    chosen: int
    timings_ms: dict[str, float] = field(default_factory=dict)  # itnet, composed, rivals, total
    iterations: int = 0  # IT-Net steps of both clouds' poses
    considered: int = 0  # hypotheses the rivals were picked from (0: the composed pose sure)
    scale: float = 1.0  # B's RMS radius about its centroid (the unit of the relative distances)
    inlier_distance: float = 0.0  # the fitness's inlier distance, B's units
    icp_distance: float = 0.0  # ICP's final correspondence distance, B's units (0: no ICP)

    @property
    def probability(self) -> float:
        """The calibrated probability that the answer is right."""
        return self.hypotheses[self.chosen].probability

    def runner_up(self) -> Hypothesis | None:
        """The likeliest candidate that is another alignment than the answer (None: none)."""
        best = self.hypotheses[self.chosen].T_b_from_a
        others = [h for h in self.hypotheses
                  if not same_alignment(h.T_b_from_a, best, self.scale, 10.0, 0.1)]  # fmt: skip
        return max(others, key=lambda h: h.probability, default=None)

    def to_dict(self) -> dict:
        """JSON form (the CLI's ``--json``)."""
        t = self.T_b_from_a
        chosen, second = self.hypotheses[self.chosen], self.runner_up()
        return {
            "T_b_from_a": t.tolist(),
            "rotation_deg": round(float(rotation_angle_deg(t[:3, :3])), 4),
            "translation": t[:3, 3].tolist(),
            "iterations": self.iterations,
            "elapsed_ms": round(self.timings_ms.get("total", 0.0), 3),
            "timings_ms": {k: round(v, 3) for k, v in self.timings_ms.items()},
            "hypothesis": chosen.source,
            "probability": round(chosen.probability, 4),
            "fitness": round(chosen.fitness, 4),
            "runner_up": None if second is None else {
                "hypothesis": second.source, "probability": round(second.probability, 4)},
            "considered": self.considered,
            "scale": float(f"{self.scale:.5g}"),
            "inlier_distance": float(f"{self.inlier_distance:.5g}"),
            "icp_distance": float(f"{self.icp_distance:.5g}"),
            "refined": chosen.initial is not None,
            "T_canonical_from_a": self.pose_a.to_dict(),
            "T_canonical_from_b": self.pose_b.to_dict(),
            "hypotheses": [h.to_dict() for h in self.hypotheses],
        }  # fmt: skip


def _pose(estimate: PoseEstimator, points: NDArray, name: str, up: NDArray | None) -> PoseEstimate:
    """The cloud's served pose; what the estimator raises comes back as CloudEstimateError."""
    try:
        return estimate(points, up)
    except Exception as err:  # the estimator's own errors, labelled with the cloud they concern
        raise CloudEstimateError(name, err) from err


def _poses(estimate: PoseEstimator, a: NDArray, b: NDArray,
           ups: list[NDArray | None]) -> tuple[PoseEstimate, PoseEstimate]:  # fmt: skip
    """Both clouds' served poses: together where the estimator can (``together``: admitted as
    one request), else each on its own."""
    together = getattr(estimate, "together", None)
    if together is not None:
        pose_a, pose_b = together([a, b], ups)
        return pose_a, pose_b
    return _pose(estimate, a, "A", ups[0]), _pose(estimate, b, "B", ups[1])


class _Judge:
    """Judges candidates on the two clouds: ICP, fitness, overlap, the runs' support, and the
    calibrated probability; one per alignment."""

    def __init__(self, a: NDArray, b: NDArray, run_pairs: NDArray, options: AlignOptions) -> None:
        self.options = options
        self.scale = estimate_normalization(b).scale
        # KD-trees on at most TREE_POINTS of each cloud: a 100,000-point scan scores the same
        # on a fifth of its points, and its tree builds in a fraction of the time.
        self.a = Cloud(sample(a, TREE_POINTS, options.seed))
        self.b = Cloud(sample(b, TREE_POINTS, options.seed + 1))
        self.run_pairs = run_pairs
        self.best_composed = 0.0  # the composed poses' best fitness
        self.refiner = None
        if options.refine:
            from itnet.alignment.refine import IcpRefiner

            voxel = options.voxel
            if voxel is None:
                voxel = 0.05 if max(len(a), len(b)) > 20_000 else 0.0
            self.refiner = IcpRefiner(a, b, options.icp_distance * self.scale,
                                      voxel=voxel * self.scale, tolerance=options.icp_tolerance,
                                      coarse_points=options.coarse_points)  # fmt: skip

    def overlap(self, poses: NDArray, distance: float, points: int) -> tuple[NDArray, NDArray]:
        """(fitness (H,), rmse (H,)) of poses (H, 4, 4) at ``distance`` radii of B."""
        return overlap(poses, self.a, self.b, distance * self.scale, points, self.options.seed)

    def loose(self, poses: NDArray) -> NDArray:
        """How much A lands on B at the ranking distance (twice ICP's), on a few points (H,)."""
        return self.overlap(poses, 2 * self.options.icp_distance, self.options.rank_points)[0]

    def refine(self, hypotheses: list[Hypothesis], finalists: int | None = None,
               deadline: float = np.inf, finish_by: float = np.inf) -> list[int]:  # fmt: skip
        """ICP's coarse stage on each in turn, its fine stage on the ``finalists`` that fit best
        after it (None: all); each refined one then holds its refined pose, its start in
        ``initial``. ``deadline`` (a ``time.perf_counter()`` value): no coarse stage starts
        after it (the first always runs), and the hypotheses left are not refined;
        ``finish_by``: no fine stage starts after it (a finalist keeps its coarse pose) -> the
        indices of the finalists."""
        assert self.refiner is not None
        coarse: list[RefineResult] = []
        for h in hypotheses:
            if coarse and time.perf_counter() > deadline:
                break
            coarse.append(self.refiner.refine(h.T_b_from_a, slice(1)))
        fine = set(range(len(coarse)))
        if finalists is not None and finalists < len(coarse):
            o = self.options
            fit = self.overlap(np.array([r.T_b_from_a for r in coarse]), o.inlier_distance,
                               o.score_points)[0]  # fmt: skip
            fine = set(np.argsort(-fit, kind="stable")[:finalists].tolist())
        for k, (h, first) in enumerate(zip(hypotheses, coarse)):
            finish = k in fine and time.perf_counter() <= finish_by
            done = self.refiner.refine(first.T_b_from_a, slice(1, None)) if finish else first
            h.initial, h.T_b_from_a = h.T_b_from_a, done.T_b_from_a
            h.icp = {"fitness": round(done.fitness, 4), "rmse": float(f"{done.rmse:.5g}")}
            h.source += "+icp"
        return sorted(fine)

    def judge(self, hypotheses: list[Hypothesis], composed: bool = False) -> None:
        """Fitness, overlap, support, evidence and probability of each (``composed``: these are
        the composed poses, whose best fitness a rival's gain is measured from)."""
        o = self.options
        poses = np.array([h.T_b_from_a for h in hypotheses])
        fitness, rmse = self.overlap(poses, o.inlier_distance, o.score_points)
        loose = self.loose(poses)
        starts = np.array([h.T_b_from_a if h.initial is None else h.initial for h in hypotheses])
        backing = support(starts, self.run_pairs, self.scale)
        if composed:
            self.best_composed = float(fitness.max())
        for h, fit, err, near, backs in zip(hypotheses, fitness, rmse, loose, backing):
            h.fitness, h.rmse, h.loose_fitness = float(fit), float(err), float(near)
            move = None if h.initial is None else icp_move(h.initial, h.T_b_from_a, self.scale)
            gain = 0.0 if composed else float(fit) - self.best_composed
            h.evidence = feature_row(float(fit), float(near), float(backs), h.served, h.turned,
                                     move, gain)  # fmt: skip
        for h, p in zip(hypotheses, probability(np.array([h.evidence for h in hypotheses]))):
            h.probability = float(p)


def align_clouds(
    points_a: ArrayLike,
    points_b: ArrayLike,
    estimate: PoseEstimator,
    options: AlignOptions,
    up_a: ArrayLike | None = None,
    up_b: ArrayLike | None = None,
    started: float | None = None,
) -> Alignment:
    """Cloud A (N, 3) and B (M, 3), each in its own frame and unit-consistent -> Alignment.
    ``up_a``, ``up_b`` (3,, any length): which way is up in each cloud, where known (see the
    module); ValueError for one that is not a direction. ``started``: the budget's clock (a
    ``time.perf_counter()`` value; default now).

    ``estimate`` maps a cloud (K, 3) to its served pose (``PoseEstimator``); what it raises
    comes back as CloudEstimateError (``__cause__``: the original). Raises
    ``itnet.alignment.refine.RefineUnavailable`` when refinement needs open3d and it is absent.
    """
    if options.candidates < 1:
        raise ValueError("candidates must be >= 1")
    start = time.perf_counter() if started is None else started
    ups = [None if up is None else unit_up(up) for up in (up_a, up_b)]
    a = np.asarray(points_a, dtype=np.float64)
    b = np.asarray(points_b, dtype=np.float64)
    pose_a, pose_b = _poses(estimate, a, b, ups)
    t_itnet = time.perf_counter()

    every = build_hypotheses(pose_a.candidates(), pose_b.candidates(),
                             symmetry_rotations(options.symmetry))  # fmt: skip
    judge = _Judge(a, b, np.array([h.T_b_from_a for h in every if not h.turned]), options)
    composed, costs_ms = _composed(every[0], judge, options.refine)
    t_composed = time.perf_counter()
    upright = ups[0] is not None and ups[1] is not None
    rivals, considered = _rivals(every, composed, judge, options, start, costs_ms, upright)
    if upright and rivals and max(h.probability for h in [*composed, *rivals]) < options.sure:
        rivals += _swept(composed[0], a, b, ups[1], judge, options, start, costs_ms)
    hypotheses = [*composed, *rivals]
    chosen = _chosen(hypotheses, len(composed), judge.scale)
    done = time.perf_counter()
    return Alignment(
        T_b_from_a=hypotheses[chosen].T_b_from_a,
        pose_a=pose_a,
        pose_b=pose_b,
        hypotheses=hypotheses,
        chosen=chosen,
        timings_ms={
            "itnet": (t_itnet - start) * 1e3,
            "composed": (t_composed - t_itnet) * 1e3,
            "rivals": (done - t_composed) * 1e3,
            "total": (done - start) * 1e3,
        },
        iterations=pose_a.iterations + pose_b.iterations,
        considered=considered,
        scale=judge.scale,
        inlier_distance=options.inlier_distance * judge.scale,
        icp_distance=options.icp_distance * judge.scale if options.refine else 0.0,
    )


def _swept(
    composed: Hypothesis,
    a: NDArray,
    b: NDArray,
    up_b: NDArray | None,
    judge: _Judge,
    options: AlignOptions,
    start: float,
    costs_ms: tuple[float, float],
) -> list[Hypothesis]:
    """Where both clouds' ups are known and the rivals judged leave every hypothesis in doubt
    (under ``options.sure``): the composed pose turned about B's up (``up_b``;
    ``hypotheses.yaw_sweep``, ``options.sweep`` turns), each given ICP's coarse stage while the
    budget left since ``start`` allows, the best ``options.finalists`` its fine one, and those
    judged -> the swept finalists (none where the budget holds too few turns). ``costs_ms``:
    the composed pose's ICP (coarse and fine) and judging times."""
    if not (options.refine and options.sweep and up_b is not None):
        return []
    icp_ms, judge_ms = costs_ms
    # each turn's coarse stage costs about half the composed pose's ICP; a finalist's fine
    # stage, from further off than the composed pose's, up to a whole one; the finalists are
    # judged as the composed poses were, twice over for safety
    deadline = finish_by = np.inf
    if options.budget_ms is not None:
        end_ms = options.budget_ms * (1.0 - SWEEP_MARGIN)
        finish_by = start + (end_ms - icp_ms - 2 * judge_ms) / 1e3
        deadline = finish_by - icp_ms * (options.finalists - 1) / 1e3
        if deadline - time.perf_counter() < SWEEP_LEAST * icp_ms / 2e3:
            return []
    swept = yaw_sweep(composed.T_b_from_a, up_b, a.mean(0), b.mean(0), options.sweep)
    swept = [swept[k] for k in judge.refine(swept, options.finalists, deadline, finish_by)]
    judge.judge(swept)
    return swept


def _composed(
    first: Hypothesis, judge: _Judge, refine: bool
) -> tuple[list[Hypothesis], tuple[float, float]]:
    """The composed pose (``first``) and, with ``refine``, a copy of it refined by ICP, both
    judged -> (them, (ICP's time, the judging's time) in ms)."""
    composed = [first]
    icp_ms = 0.0
    if refine:
        composed.append(Hypothesis(first.T_b_from_a.copy(), first.source, served=True))
        t_icp = time.perf_counter()
        judge.refine(composed[1:])
        icp_ms = (time.perf_counter() - t_icp) * 1e3
    t_judge = time.perf_counter()
    judge.judge(composed, composed=True)
    return composed, (icp_ms, (time.perf_counter() - t_judge) * 1e3)


def _chosen(hypotheses: list[Hypothesis], composed: int, scale: float) -> int:
    """The likeliest hypothesis; where that is the composed pose and ICP refined it
    (``composed`` is 2) into the same alignment, the refined one: the same, sharpened."""
    chosen = choose([h.probability for h in hypotheses])
    if chosen == 0 and composed == 2:
        refined, plain = hypotheses[1].T_b_from_a, hypotheses[0].T_b_from_a
        if same_alignment(refined, plain, scale, 10.0, 0.1):
            return 1
    return chosen


def _rivals(
    every: list[Hypothesis],
    composed: list[Hypothesis],
    judge: _Judge,
    options: AlignOptions,
    start: float,
    costs_ms: tuple[float, float],
    upright: bool = False,
) -> tuple[list[Hypothesis], int]:
    """(the rivals of the composed pose, refined and judged; the hypotheses considered for them,
    0 where none were): looked for only where the composed pose is in doubt and the budget left
    since ``start`` holds them. ``costs_ms``: the composed pose's ICP and judging times;
    ``upright``: both poses were held upright."""
    icp_ms, judge_ms = costs_ms
    # The composed pose is in doubt where it is not likely right, or where a rival lands more of
    # A on B at the loose distance (a quick count over every hypothesis, before any ICP). Two
    # poses held upright are always in doubt: the calibration saw no such pair, and a box-like
    # object's runs agree on a quarter turn as readily as on the right pose.
    rest = every[1:] if options.rivals else []
    loose = judge.loose(np.array([h.T_b_from_a for h in rest])) if rest else np.zeros(0)
    sure = not upright and max(h.probability for h in composed) >= options.sure
    rivalled = bool(len(loose)) and float(loose.max()) > every[0].loose_fitness + DOUBT_LOOSE
    # The rivals cost about the composed pose's ICP for each finalist and half of it (the coarse
    # stage) for each other candidate, and its judging twice (the ranking, the judging).
    rivals_ms = icp_ms * (options.candidates + options.finalists) / 2 + 2 * judge_ms
    left_ms = np.inf
    if options.budget_ms is not None:
        left_ms = options.budget_ms - (time.perf_counter() - start) * 1e3
    if not (rest and (rivalled or not sure) and left_ms >= rivals_ms):
        return [], 0
    keep = distinct(every, np.concatenate([[np.inf], loose]), options.candidates + 1,
                    judge.scale, options.distinct_deg, options.distinct_shift)  # fmt: skip
    rivals = [every[k] for k in keep if k != 0]
    if options.refine and rivals:
        judge.refine(rivals, options.finalists)
    if rivals:
        judge.judge(rivals)
    return rivals, len(every)
