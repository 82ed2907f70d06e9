"""``plan(model, request)``: a request turned, once, into what the anytime loop will do.

The plan says how the runs start (how many, from which rotations, on which points), what each
step does (fuse the runs, hold them upright) and which finishing stages run after the last step
(``itnet.pose.stages``), in order. It depends on the model's card, the request and the model's
step time measured on an idle machine at load, never on the load of the moment: the same
request gets the same plan, and so the same pose, whichever way it came in, loaded or idle
(where a loaded machine cannot serve it, the service refuses it instead).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cache

import numpy as np
from numpy.typing import NDArray

from itnet.geometry import viewing_axis_turns
from itnet.pose.cloud import Limits, validate_up, validate_viewpoint
from itnet.pose.errors import BadCloudError, BudgetTooSmallError
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import LoadedModel
from itnet.pose.stages import STAGES, Stage
from itnet.upright import upright_starts

MAX_ENSEMBLE = 16  # runs one request may fuse (each costs a share of the step)
ENSEMBLE_SUBSET = 0.8  # a fused run's share of a cloud no larger than the model's point count
CONVERGE_ROTATION_DEG = 0.01  # an update smaller than this and CONVERGE_TRANSLATION stops the run
CONVERGE_TRANSLATION = 1e-4  # normalised units (the cloud's RMS radius)


@dataclass(frozen=True)
class PosePlan:
    """What one request's run does. ``starts`` (runs, 3, 3): the rotations the runs begin from
    (float32, the normalised frame); ``fuse``: each estimate is the runs' robust fusion (else
    the first run's); ``up`` (3,) unit, held from step ``up_free`` on; ``stages``: the finishing
    stages that are on, in order."""

    model: LoadedModel
    request: PoseRequest
    budget_ms: float
    max_iterations: int
    starts: NDArray[np.float32]
    up: NDArray[np.float64] | None
    up_free: int
    viewpoint: NDArray[np.float64] | None
    stages: tuple[Stage, ...]
    limits: Limits
    seed: int = 0
    # successive halving: after this many iterations, the runs the verifier finds likeliest
    # go on, this many of them (None: every run to the end)
    halving: tuple[int, int] | None = None
    # an update below (degrees, normalised distance: the cloud's RMS radius) ends the run
    converge: tuple[float, float] = (CONVERGE_ROTATION_DEG, CONVERGE_TRANSLATION)
    # the most points a run sees of the cloud (None: the model card's count)
    points: int | None = None
    # coarse first steps: the first ITERATIONS steps see at most POINTS of each run's points (a
    # step costs about linearly in runs x points; None: every step sees them all)
    coarse: tuple[int, int] | None = None

    @property
    def runs(self) -> int:
        return len(self.starts)

    @property
    def halving_at(self) -> int:
        """The iteration after which the runs are halved (0: never)."""
        return 0 if self.halving is None or self.halving[1] >= self.runs else self.halving[0]

    @property
    def halving_keep(self) -> int:
        """The runs kept at the halving (all of them without one)."""
        return self.halving[1] if self.halving is not None and self.halving_at else self.runs

    def run_steps(self, iterations: int, start: int = 0, now: int | None = None) -> int:
        """Run steps (one run, one iteration each) from iteration ``start`` to ``iterations``
        with ``now`` runs stepping (default: the plan's): the halving's runs after it."""
        runs = self.runs if now is None else now
        at = self.halving_at
        if at <= start or at == 0:
            return max(0, iterations - start) * runs
        before = max(0, min(at, iterations) - start)
        return before * runs + max(0, iterations - at) * self.halving_keep

    @property
    def coarse_at(self) -> int:
        """The iterations that step on the coarse points (0: none)."""
        return 0 if self.coarse is None else self.coarse[0]

    def step_points(self, iteration: int, run_points: int) -> int:
        """Points each run steps on at ``iteration`` (0-based), of its ``run_points``."""
        if iteration < self.coarse_at:
            return min(run_points, self.coarse[1])  # type: ignore[index]
        return run_points

    def work_ms(self, iterations: int, run_points: int, one_run_ms: Callable[[int], float],
                start: int = 0, now: int | None = None) -> float:  # fmt: skip
        """The steps from iteration ``start`` to ``iterations`` (``now`` runs stepping, as
        ``run_steps``) at ``one_run_ms(points)`` a run-step: the coarse ones at their points."""
        at = self.coarse_at
        if at <= start:
            return self.run_steps(iterations, start, now) * one_run_ms(run_points)
        coarse = self.run_steps(min(iterations, at), start, now)
        fine = self.run_steps(iterations) - self.run_steps(at) if iterations > at else 0
        return coarse * one_run_ms(self.step_points(start, run_points)) + fine * one_run_ms(
            run_points
        )

    @property
    def stage_names(self) -> tuple[str, ...]:
        """The finishing stages that are on, in order."""
        return tuple(stage.name for stage in self.stages)

    @property
    def fuse(self) -> bool:
        return self.runs > 1

    @property
    def most_points(self) -> int:
        """The most points a run sees: the plan's ``points``, else the model card's count."""
        return self.model.card.points if self.points is None else self.points

    def run_points(self, cloud_points: int) -> int:
        """Points each run sees of a cloud of ``cloud_points``: ``most_points`` for a single
        run (a smaller cloud whole); fused runs each their own subset (``subset_points``)."""
        if self.fuse:
            return self.subset_points(cloud_points)
        return min(self.most_points, cloud_points)

    def subset_points(self, cloud_points: int) -> int:
        """One fused run's subset: ENSEMBLE_SUBSET of the cloud, within [min_points,
        ``most_points``]."""
        share = max(self.limits.min_points, int(ENSEMBLE_SUBSET * cloud_points))
        return min(self.most_points, share)

    def idle_run_ms(self, points: int) -> float:
        """One run's step on ``points`` points, on an idle machine (as measured at load)."""
        return self.model.run_step_ms(1, points, idle=True)

    def first_step_ms(self, cloud_points: int | None = None) -> float:
        """One step of every run on an idle machine: the least a served pose costs."""
        points = self.run_points(cloud_points or self.most_points)
        return self.model.run_step_ms(self.runs, points, idle=True)


def fitting_ensemble(recommended: int, work_ms: Callable[[int], float],
                     available_ms: float) -> int:  # fmt: skip
    """The runs a request that names none gets: the card's ``recommended``, halved until the
    plan of that many runs fits ``available_ms`` (``work_ms(runs)``: its steps on an idle
    machine); at least 1. Unknown timing (``work_ms`` 0) keeps ``recommended``. Fewer runs that
    reach their iterations beat more that stop early (the anytime curve still rises at 10)."""
    k = recommended
    while k > 1 and work_ms(k) > available_ms:
        k //= 2
    return k


def plan(
    model: LoadedModel,
    request: PoseRequest,
    limits: Limits = Limits(),
    spent_ms: float = 0.0,
    seed: int = 0,
) -> PosePlan:
    """The plan of ``request`` on ``model`` (its ``model`` field is already resolved to it);
    ``spent_ms``: what the budget already paid before the run (the classification of ``auto``).
    The runs follow the card's schedule (coarse first steps, successive halving: the same
    accuracy for a fraction of the steps, as the card's plan_evaluation measured) unless the
    request's ``schedule`` is false (every run on all its points every step, as a path measured
    without it asks); the runs a budget holds are counted on that plan; each run sees at most
    the request's ``points_per_run`` (default: the card's), and the runs are sized at that count.
    Raises BadCloudError (a 422) for what the request cannot have: a budget or iteration cap
    over the limits, ``up`` or ``viewpoint`` that are not directions or points, a model that
    needs ``up`` without it, or a finishing stage asked for that this model or request cannot
    run (the stage says why)."""
    card = model.card
    if request.budget_ms > limits.max_budget_ms:
        raise BadCloudError(
            f"budget_ms {request.budget_ms:g} is over the limit of {limits.max_budget_ms:g} ms"
        )
    iterations = request.max_iterations or min(card.recommended_iterations, limits.max_iterations)
    if iterations > limits.max_iterations:
        raise BadCloudError(
            f"max_iterations {iterations} is over the limit of {limits.max_iterations}"
        )
    up = None if request.up is None else validate_up(request.up)
    if up is None and card.requires_up:
        raise BadCloudError(
            f"model {card.name!r} needs 'up', which way is up in the cloud ([x, y, z]; 'x,y,z' "
            "in a query): its poses are measured, and served, only with it (GET /v1/models: "
            "'requires_up')"
        )
    viewpoint = None if request.viewpoint is None else validate_viewpoint(request.viewpoint)
    least = model.run_step_ms(1, 1, idle=True)  # the cheapest step there is, on an idle machine
    if request.budget_ms < least:
        raise BudgetTooSmallError(
            f"budget_ms {request.budget_ms:g} is below one step of model {card.name!r} (about "
            f"{least:.2g} ms at the least on this machine): no pose fits it"
        )

    base = PosePlan(
        model=model,
        request=request,
        budget_ms=float(request.budget_ms),
        max_iterations=iterations,
        starts=_starts(1, up, card.up_free_steps),
        up=up,
        up_free=card.up_free_steps if up is not None else 0,
        viewpoint=viewpoint,
        stages=(),
        limits=limits,
        seed=seed,
        points=request.points_per_run,
    )
    available = request.budget_ms - spent_ms
    schedule = request.schedule is not False

    @cache  # each count of runs sized once: the one chosen is not sized again
    def sized(runs: int) -> PosePlan:
        return _sized(base, runs, schedule)

    def work_ms(runs: int) -> float:
        """The steps of ``runs`` runs as they would be planned, on an idle machine."""
        return sized(runs).work_ms(iterations, base.most_points, base.idle_run_ms)

    runs = request.ensemble
    if runs is None:
        runs = fitting_ensemble(card.recommended_ensemble, work_ms, available)
    if not (1 <= runs <= MAX_ENSEMBLE):
        raise BadCloudError(f"ensemble must be in [1, {MAX_ENSEMBLE}], got {runs}")
    return replace(sized(runs),
                   starts=_starts(runs, up, card.up_free_steps),
                   stages=_stages(model, request, runs))  # fmt: skip


def _sized(base: PosePlan, runs: int, schedule: bool) -> PosePlan:
    """``base`` with ``runs`` runs (as many starts; what their work needs, not yet turned apart
    or given their stages): on the card's schedule where ``schedule`` and the card has one (its
    first steps on fewer points, then the runs the verifier finds likeliest), else every run on
    all its points every step. A schedule measured on fused runs leaves a single run every
    step; a card that fuses no runs measured its schedule on its single run."""
    card = base.model.card
    full = replace(base, starts=np.repeat(base.starts, runs, axis=0))
    if not schedule or (card.coarse_steps is None and card.halving is None):
        return full
    if runs == 1 and card.recommended_ensemble > 1:
        return full
    return replace(full, halving=card.halving, coarse=card.coarse_steps)


def _starts(runs: int, up: NDArray | None, up_free: int) -> NDArray[np.float32]:
    """The runs' starting rotations (runs, 3, 3): stood up by ``up`` with yaw turns 360/runs
    apart (unless the card's first steps run free), else turns about the viewing axis (z)
    360/runs apart, the first the identity. Runs that start apart fall into different basins
    where a view is ambiguous and agree where it is not, which is what the fusion needs."""
    if up is not None and up_free == 0:
        return upright_starts(up, runs).astype(np.float32)
    if runs > 1:
        return viewing_axis_turns(runs).astype(np.float32)
    return np.eye(3, dtype=np.float32)[None]


def _stages(model: LoadedModel, request: PoseRequest, runs: int) -> tuple[Stage, ...]:
    """The finishing stages that are on: each asked for by its request field (refused with its
    reason where it cannot run), or on by its default where the request leaves it open."""
    on = []
    for stage in STAGES:
        asked = getattr(request, stage.name, None)  # a stage without a field: its default
        if asked:
            reason = stage.refusal(model, request, runs)
            if reason is not None:
                raise BadCloudError(reason)
        if asked or (asked is None and stage.default(model, request, runs)):
            on.append(stage)
    return tuple(on)
