"""The anytime loop: the only place that iterates IT-Net steps. CLI, HTTP and WebSocket consume it.

    run = AnytimeRun(model, cloud, budget_ms=50)
    for estimate in run:          # one Estimate per iteration, as soon as it exists
        ...
    run.stopped_by                # 'budget' | 'max_iterations' | 'converged' | 'cancelled'

Per request: validate the cloud, normalise it (``itnet.preprocess``: centroid, RMS radius),
subsample it to the model's point count if larger (seeded, so the same cloud gives the same
answer; a smaller cloud goes in whole: repeats would not change the pose, only the cost), then
loop: predict the next step's time, stop if it would overrun the budget, run the step, compose,
and yield the pose in the input's units. After the last step, a model whose card declares the
category's mirror symmetry has the final pose finished by it (``itnet.mirror``) when the budget
still holds that; the streamed estimates are the network's, ``result()`` the finished pose.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.basin import (
    PROBE_DEG,
    PROBE_STEPS,
    basin_drift,
    canonical_points,
    firm_anchor,
    likeliest_run,
    probe_turns,
)
from itnet.centre import centre_finished
from itnet.fusion import fuse_poses, medoid_index
from itnet.geometry import (
    invert_rigid,
    matrix_to_quat_wxyz,
    quat_wxyz_to_xyzw,
    rotation_angle_deg,
    viewing_axis_turns,
)
from itnet.mirror import mirror_finished
from itnet.preprocess import (
    DegenerateCloudError,
    Normalization,
    cap_points,
    estimate_normalization,
    pose_from_normalized,
)
from itnet.service.runtime import LoadedModel
from itnet.upright import held_upright, unit_up, upright_starts

STOP_REASONS = ("budget", "max_iterations", "converged", "cancelled")
# Larger coordinates overflow the normalisation's squares (1e200 ** 2 is inf in float64) and
# would be called degenerate; 1e12 leaves float64 room for any physical unit.
MAX_COORDINATE = 1e12
MAX_ENSEMBLE = 16  # runs one request may fuse (each costs a share of the step)
RECHECK_RUNS = 4  # runs a doubted single run is rechecked with, where the card gives none
ENSEMBLE_SUBSET = 0.8  # an ensemble run's share of a cloud no larger than the model's point count


def fitting_ensemble(recommended: int, run_step_ms: float, iterations: int,
                     available_ms: float) -> int:  # fmt: skip
    """The runs a request that names none gets: the card's ``recommended``, halved until
    ``iterations`` fused steps fit ``available_ms`` by the running estimate of one run's step
    (``run_step_ms``: a step of K runs costs about K of them); at least 1. Unknown timing
    (``run_step_ms`` 0, before the first step) keeps ``recommended``. Fewer runs that reach
    their iterations beat more that stop early (the anytime curve still rises at 10)."""
    k = recommended
    while k > 1 and k * run_step_ms * iterations > available_ms:
        k //= 2
    return k


def _step_load(runs: int, points: int, model_points: int) -> float:
    """A step's cost in steps of one run of the model's point count: about proportional to the
    points, with a floor for the fixed part."""
    return max(runs * points / model_points, 0.25)


def _run_subset(model_points: int, min_points: int, cloud_points: int) -> int:
    """Points of one ensemble run's subset: ENSEMBLE_SUBSET of the cloud, within [min_points,
    the model's point count]."""
    return min(model_points, max(min_points, int(ENSEMBLE_SUBSET * cloud_points)))


class BadCloudError(ValueError):
    """The cloud cannot be used: wrong shape, non-finite values, too few/many points, degenerate."""


@dataclass(frozen=True)
class Limits:
    min_points: int = 32
    max_points: int = 1_000_000
    max_budget_ms: float = 60_000.0
    max_iterations: int = 200


@dataclass(frozen=True)
class Estimate:
    """The pose after ``iteration`` steps. ``pose`` is T_canonical_from_input (4x4, input units),
    computed from the normalised pose when first read (the loop itself never needs it)."""

    iteration: int
    pose_normalized: NDArray[np.float32]  # (4, 4), the network's frame
    normalization: Normalization
    elapsed_ms: float
    update_rotation_deg: float  # size of this iteration's update
    update_translation: float  # in the input's units

    @cached_property
    def pose(self) -> NDArray[np.float64]:
        return pose_from_normalized(self.pose_normalized.astype(np.float64), self.normalization)

    def to_dict(self, quat_wxyz: NDArray[np.float64] | None = None) -> dict:
        """The JSON form (``quat_wxyz``: the pose's quaternion, if already computed)."""
        return {
            "iteration": self.iteration,
            **pose_fields(self.pose, quat_wxyz),
            "elapsed_ms": round(self.elapsed_ms, 3),
            "update_rotation_deg": round(self.update_rotation_deg, 5),
            "update_translation": self.update_translation,
        }


def estimates_to_dicts(estimates: Sequence[Estimate]) -> list[dict]:
    """``Estimate.to_dict`` of each, their quaternions converted in one batch: a reply's ten
    estimates took 0.77 ms one by one on 2 cores (numpy's per-call cost, ten times), which every
    request paid inside its budget."""
    if not estimates:
        return []
    quats = matrix_to_quat_wxyz(np.stack([e.pose[:3, :3] for e in estimates]))
    return [e.to_dict(q) for e, q in zip(estimates, quats, strict=True)]


def pose_fields(pose: NDArray[np.float64], quat_wxyz: NDArray[np.float64] | None = None) -> dict:
    """The JSON form of a pose: matrix, both quaternion orders, translation (``quat_wxyz``: the
    rotation's quaternion, if already computed)."""
    quat = matrix_to_quat_wxyz(pose[:3, :3]) if quat_wxyz is None else quat_wxyz
    return {
        "T_canonical_from_input": pose.tolist(),
        "quat_wxyz": quat.tolist(),
        "quat_xyzw": quat_wxyz_to_xyzw(quat).tolist(),
        "translation": pose[:3, 3].tolist(),
    }


def validate_cloud(points: ArrayLike, limits: Limits) -> NDArray[np.float64]:
    """Any array-like -> (N, 3) float64, or BadCloudError saying what is wrong."""
    try:
        cloud = np.asarray(points, dtype=np.float64)
    except (ValueError, TypeError) as err:
        raise BadCloudError(f"points must be a list of [x, y, z] numbers ({err})") from None
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise BadCloudError(f"points must have shape (N, 3), got {cloud.shape}")
    if not np.isfinite(cloud).all():
        bad = int((~np.isfinite(cloud)).any(axis=1).sum())
        raise BadCloudError(f"{bad} point(s) have NaN or infinite coordinates")
    if len(cloud) < limits.min_points:
        raise BadCloudError(f"{len(cloud)} points is too few (the minimum is {limits.min_points})")
    if len(cloud) > limits.max_points:
        raise BadCloudError(f"{len(cloud)} points is too many (the maximum is {limits.max_points})")
    if np.abs(cloud).max(initial=0.0) > MAX_COORDINATE:
        raise BadCloudError(
            f"coordinates out of range: |x|, |y|, |z| must be at most {MAX_COORDINATE:g} "
            f"(got {np.abs(cloud).max():.3g}); send the cloud in a smaller unit"
        )
    return cloud


def _normalization(cloud: NDArray[np.float64]) -> Normalization:
    try:
        return estimate_normalization(cloud)
    except DegenerateCloudError as err:
        raise BadCloudError(str(err)) from None


def _viewpoint(viewpoint: ArrayLike) -> NDArray[np.float64]:
    """The sensor's position (3,), finite, or BadCloudError."""
    try:
        point = np.asarray(viewpoint, dtype=np.float64)
    except (TypeError, ValueError):
        point = np.empty(0)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise BadCloudError("viewpoint must be three finite numbers: the sensor's x, y, z")
    return point


def validate_up(up: ArrayLike) -> NDArray[np.float64]:
    """A request's up direction -> its unit vector (3,); BadCloudError saying what is wrong
    (not three finite numbers, or zero)."""
    try:
        return unit_up(np.asarray(up, dtype=np.float64).reshape(-1))
    except (TypeError, ValueError) as err:
        raise BadCloudError(str(err)) from None


def _rotations(starts: ArrayLike) -> NDArray[np.float32]:
    """Starting rotations (3, 3) or (B, 3, 3) -> (B, 3, 3), checked."""
    r = np.asarray(starts, dtype=np.float64)
    r = r[None] if r.ndim == 2 else r
    if r.ndim != 3 or r.shape[1:] != (3, 3) or len(r) == 0:
        raise BadCloudError("starts must be a 3x3 rotation matrix or a stack of them")
    if not np.allclose(r @ r.transpose(0, 2, 1), np.eye(3), atol=1e-5):
        raise BadCloudError("starts must be rotation matrices (orthonormal)")
    if np.any(np.linalg.det(r) < 0):
        raise BadCloudError("starts must be rotations (determinant +1), not reflections")
    return r.astype(np.float32)


class AnytimeRun(Iterator[Estimate]):
    """One request's anytime estimation; iterate it for the estimates. Thread-safe ``cancel``."""

    def __init__(
        self,
        model: LoadedModel,
        points: ArrayLike,
        budget_ms: float = 50.0,
        max_iterations: int | None = None,
        converge_rotation_deg: float = 0.01,
        converge_translation: float = 1e-4,
        limits: Limits = Limits(),
        seed: int = 0,
        started: float | None = None,
        reserve_ms: float = 0.0,
        starts: ArrayLike | None = None,
        points_per_step: int | None = None,
        ensemble: int | None = None,
        mirror: bool | None = None,
        centre: bool | None = None,
        viewpoint: ArrayLike | None = None,
        up: ArrayLike | None = None,
        verify: bool | None = None,
        recheck: bool | None = None,
        sharing: float = 1.0,
    ) -> None:
        # The budget clock: from ``started`` (a time.perf_counter() value, e.g. when the request
        # arrived, so that decoding and queueing count against the budget), else from now.
        self.started = time.perf_counter() if started is None else started
        if not (0 < budget_ms <= limits.max_budget_ms):
            raise BadCloudError(
                f"budget_ms must be in (0, {limits.max_budget_ms:g}], got {budget_ms}"
            )
        max_iterations = (
            model.card.recommended_iterations if max_iterations is None else max_iterations
        )
        if not (1 <= max_iterations <= limits.max_iterations):
            raise BadCloudError(
                f"max_iterations must be in [1, {limits.max_iterations}], got {max_iterations}"
            )
        cloud = validate_cloud(points, limits)
        if points_per_step is not None and points_per_step < limits.min_points:
            raise BadCloudError(f"points_per_step must be at least {limits.min_points}")
        # Kept back from the budget for handing the reply back after the last step (the service
        # measures it: service/handback.py); never more than half of the budget.
        self.reserve_ms = min(max(0.0, reserve_ms), float(budget_ms) / 2)
        if ensemble is None:  # the card's, as many as the budget holds, unless the caller chose
            own = starts is not None or points_per_step is not None  # its own starts or subsets
            size = _run_subset(model.card.points, limits.min_points, len(cloud))
            available = budget_ms - self.reserve_ms - (time.perf_counter() - self.started) * 1e3
            # ``sharing``: estimates in flight per step slot (the service's count): each step
            # waits for the others', so the budget holds that many times fewer runs' steps
            run_ms = model.predicted_step_ms() * max(size / model.card.points, 0.25)
            run_ms *= max(1.0, sharing)
            ensemble = (
                1
                if own
                else fitting_ensemble(
                    model.card.recommended_ensemble, run_ms, max_iterations, available
                )
            )
        if not (1 <= ensemble <= MAX_ENSEMBLE):
            raise BadCloudError(f"ensemble must be in [1, {MAX_ENSEMBLE}], got {ensemble}")
        if ensemble > 1 and (starts is not None or points_per_step is not None):
            raise BadCloudError("ensemble cannot be combined with starts or points_per_step")
        if mirror and not model.card.mirror:
            raise BadCloudError(
                f"model {model.card.name!r} declares no mirror symmetry (its card has no "
                "mirror_planes): mirror cannot finish its poses"
            )
        # Finish the final pose by the category's mirror symmetry: by default wherever the card
        # declares it, for a single run (validation: +0.8 to +5.3 points), and for fused runs
        # where the card says so (mirror_fused; session 19's validation, 8 runs in 80 ms: chair
        # +2.6 / +1.9 points, bathtub -2.3 / -1.1), never for runs from the caller's own starts
        # or subsets (alignment's hypotheses, whose every pose is used, not the last estimate).
        if mirror is None:
            mirror = (
                model.card.mirror
                and (ensemble == 1 or model.card.mirror_fused)
                and starts is None
                and points_per_step is None
            )
        self.mirror = bool(mirror)
        self.mirror_planes: list[str] | None = None  # once finished: the planes that finished it
        # Where the fusion's medoid does not hold its pose, anchor the fused pose by the run that
        # sits most firmly in its basin (itnet.basin), after the last step and before the
        # mirror, where the budget still holds the probes: by default where the card says so
        # (verify_fused; the chair, session 33: 4 runs on the test views, paper +1.4 ± 0.5
        # points, occluded +1.2 ± 0.6; docs/ensemble.md), never for runs held upright.
        if verify and ensemble == 1:
            raise BadCloudError(
                "verify weighs fused runs against each other: it needs ensemble > 1"
            )
        if verify and up is not None:
            raise BadCloudError("verify cannot be combined with up (the runs are held upright)")
        if verify is None:
            verify = model.card.verify_fused and ensemble > 1 and up is None
        self.verify = bool(verify)
        self.verified: bool | None = None  # once finished: whether the probes ran
        # A single run the model's learned verifier doubts (its logit below 0) is rechecked,
        # where the budget holds it: the card's recheck_runs runs from turned starts on their own
        # subsets, as many steps as it took, and the fused pose of all of them anchored on the
        # likeliest (model/verifier.py; docs/ensemble.md). By default where the card says so.
        plain = ensemble == 1 and starts is None and points_per_step is None and up is None
        if recheck and model.verifier is None:
            raise BadCloudError(
                f"model {model.card.name!r} has no verifier loaded: recheck needs one"
            )
        if recheck and not plain:
            raise BadCloudError(
                "recheck is for a single run (no ensemble, starts, points_per_step or up)"
            )
        if recheck is None:
            recheck = model.card.recheck_runs > 0 and model.verifier is not None and plain
        self.recheck = bool(recheck)
        self.recheck_runs = model.card.recheck_runs or RECHECK_RUNS
        self.rechecked: bool | None = None  # once finished, where doubted: whether runs ran
        self._cloud, self._seed, self._min_points = cloud, seed, limits.min_points
        # Which way is up in the cloud (itnet.upright): the runs start stood up, yaw turns
        # 360/K apart, and every step's pose is stood back up, so only yaw and position remain.
        self.up = None if up is None else validate_up(up)
        if self.up is None and model.card.requires_up:
            raise BadCloudError(
                f"model {model.card.name!r} needs 'up', which way is up in the cloud ([x, y, z]; "
                "'x,y,z' in a query): its poses are measured, and served, only with it (GET "
                "/v1/models: 'requires_up')"
            )
        # Where the sensor was, in the cloud's frame and units (a depth camera's cloud in its own
        # frame: the origin): the card's viewpoint correction then finishes the centre.
        self.viewpoint = None if viewpoint is None else _viewpoint(viewpoint)
        # Then finish the object centre by the card's correction (itnet.centre): the viewpoint
        # one where the request gives the sensor's position and the card has it, else the one
        # fitted on runs held upright where the request gives up and the card has it, else the
        # plain one; by default wherever one applies, except for runs from the caller's own
        # starts or subsets.
        applies = (
            model.centre is not None
            or (self.viewpoint is not None and model.centre_viewpoint is not None)
            or (self.up is not None and model.centre_up is not None)
        )
        if centre and not applies:
            raise BadCloudError(
                f"model {model.card.name!r} has no centre correction (its card has no "
                "centre_correction"
                + ("" if self.viewpoint is None else " and no centre_correction_viewpoint")
                + ("" if self.up is None else " and no centre_correction_up")
                + "): centre cannot finish its poses"
            )
        if centre is None:
            centre = applies and starts is None and points_per_step is None
        self.centre = bool(centre)
        self.centred: bool | None = None  # once finished: whether the correction moved the pose
        self.centred_by_viewpoint = False  # once finished: the viewpoint correction did it
        self.centred_by_up = False  # once finished: the correction fitted held upright did it
        self._finished = False  # _finish ran
        # Ensemble mode: K runs from turns about the viewing axis 360/K degrees apart (the first
        # from the identity), each on its own random subset of the cloud (normalised as a
        # whole), fused robustly after every step (itnet.fusion). Runs that start apart fall
        # into different basins when the view is ambiguous and agree when it is not, which is
        # what the fusion needs: on validation views (chair, table, toilet; docs/ensemble.md)
        # K = 4 turned starts gained 5.6 points on average over one run, subsets alone 2.5.
        self.ensemble = ensemble
        # the card's free steps: the first ones from the usual starts, not held (the sofa's)
        self.up_free = model.card.up_free_steps if self.up is not None else 0
        if self.up is not None and starts is not None:
            # the caller's starts (alignment's turns about up), each then stood up as a single
            # run's start would be: exactly what a request with the turned cloud gets
            if self.up_free == 0:
                starts = upright_starts(self.up, 1)[0] @ _rotations(starts)
        elif self.up is not None and self.up_free == 0:
            starts = upright_starts(self.up, ensemble)
        elif ensemble > 1:
            starts = viewing_axis_turns(ensemble)
        # Where the iterations begin: the identity, or ``starts`` (3x3 or Bx3x3), rotations of
        # the cloud about its centroid (IT-Net from several initial guesses: itnet.alignment.pipeline).
        # The B runs go through each step as one batch; the estimates and the convergence test
        # follow the first, ``poses()`` gives them all.
        turns = np.eye(3, dtype=np.float32)[None] if starts is None else _rotations(starts)
        self.pose_normalized = np.tile(np.eye(4, dtype=np.float32), (len(turns), 1, 1))
        self.pose_normalized[:, :3, :3] = turns
        rng = np.random.default_rng(seed)
        if points_per_step is None and ensemble > 1:
            norm = _normalization(cloud)
            size = _run_subset(model.card.points, limits.min_points, len(cloud))
            # the subsets normalised alone: the same points as normalising the cloud first
            inputs = [norm.apply(cap_points(cloud, size, rng)) for _ in turns]
            self.normalizations = [norm] * len(turns)
        elif points_per_step is None:
            # The whole cloud sets the centre and scale; then at most the card's point count.
            norm = _normalization(cloud)
            x = norm.apply(cap_points(cloud, model.card.points, rng))  # only the points kept
            self.normalizations, inputs = [norm] * len(turns), [x] * len(turns)
        else:
            # Each run its own seeded subset, normalised on its own: exactly what a request with
            # that subset would do (itnet.alignment.estimators.client_estimator sends those requests).
            subsets = [cap_points(cloud, points_per_step, rng) for _ in turns]
            self.normalizations = [_normalization(sub) for sub in subsets]
            inputs = [n.apply(sub) for n, sub in zip(self.normalizations, subsets)]
        self.normalization = self.normalizations[0]
        self.points = np.stack(inputs)
        # A step's cost is about proportional to its points, with a floor for the fixed part:
        # the model's step-time record is kept at the card's point count, scaled by this.
        self._load = _step_load(*self.points.shape[:2], model.card.points)
        self.model = model
        self.budget_ms, self.max_iterations = float(budget_ms), max_iterations
        self.converge = (converge_rotation_deg, converge_translation)
        self.iteration = 0
        self.stopped_by: str | None = None
        self.last: Estimate = self._estimate(self.pose_normalized[0], 0.0, 0.0)
        self._cancel = threading.Event()
        self._last_step_ms = 0.0

    def cancel(self) -> None:
        self._cancel.set()

    def elapsed_ms(self) -> float:
        return (time.perf_counter() - self.started) * 1e3

    def __next__(self) -> Estimate:
        try:
            return self._step()
        except StopIteration:
            self._finish()
            raise

    def _step(self) -> Estimate:
        if self.stopped_by is not None:
            raise StopIteration
        self.stopped_by = self._stop_reason_before_step()
        if self.stopped_by is not None:
            raise StopIteration
        # Wait for a free step slot only as long as the budget can spare (see step_slot).
        deadline = self.started + self.budget_ms / 1e3
        with self.model.step_slot(self._slack_ms() / 1e3, deadline) as free:
            if not free or self._cancel.is_set():
                self.stopped_by = "cancelled" if self._cancel.is_set() else "budget"
                raise StopIteration
            start = time.perf_counter()
            # Move the cloud by the pose so far, predict the update, compose: inside the graph.
            self.pose_normalized, delta = self.model.step(self.points, self.pose_normalized)
            if self.up is not None and self.iteration >= self.up_free:
                self.pose_normalized = held_upright(self.pose_normalized, self.up).astype(
                    np.float32
                )
            self._last_step_ms = (time.perf_counter() - start) * 1e3
        self.model.record_step_ms(self._last_step_ms / self._load)
        self.iteration += 1
        if self.ensemble > 1:
            self.last = self._moved_to(fuse_poses(self.pose_normalized, self.model.card.symmetry))
            return self._converged_or(self.last)
        d = delta[0]  # the update's angle, in scalar math (numpy's per-call cost is the loop's)
        cos = (float(d[0, 0]) + float(d[1, 1]) + float(d[2, 2]) - 1.0) / 2.0
        update_rotation = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
        update_translation = math.hypot(
            float(d[0, 3]), float(d[1, 3]), float(d[2, 3])
        )  # normalised
        self.last = self._estimate(self.pose_normalized[0], update_rotation, update_translation)
        return self._converged_or(self.last)

    def _finish(self) -> None:
        """After the last step (once): finish ``last`` by the card's mirror planes, then by its
        centre correction; none after a cancel or before any step. A run that stopped within
        the card's free steps is stood up first."""
        if self._finished:  # a second StopIteration (iterating a finished run) changes nothing
            return
        self._finished = True
        free = 0 < self.iteration <= self.up_free and self.stopped_by != "cancelled"
        if self.up is not None and free:
            self.last = self._moved_to(held_upright(self.last.pose_normalized, self.up))
        self._finish_recheck()
        self._finish_verify()
        self._finish_mirror()
        if not self.centre or self.centred is not None:
            return
        self.centred = False
        if self.stopped_by == "cancelled" or self.iteration == 0:
            return
        pose = self.last.pose_normalized.astype(np.float64)
        finished = None
        if self.viewpoint is not None and self.model.centre_viewpoint is not None:
            viewpoint = (self.viewpoint - self.normalization.center) / self.normalization.scale
            try:
                finished = centre_finished(
                    self.points[0], pose, self.model.centre_viewpoint, viewpoint
                )
                self.centred_by_viewpoint = True
            except ValueError:  # the viewpoint on the estimated centre: no direction to go by
                pass
        if finished is None and self.up is not None and self.model.centre_up is not None:
            finished = centre_finished(self.points[0], pose, self.model.centre_up)
            self.centred_by_up = True
        if finished is None and self.model.centre is not None:
            finished = centre_finished(self.points[0], pose, self.model.centre)
        if finished is not None:
            self.last = self._moved_to(finished)
            self.centred = True

    def _finish_recheck(self) -> None:
        """A single run the verifier doubts: ``recheck_runs`` runs from turned starts, each on
        its own subset of the cloud (normalised as the run's), take as many steps as the run
        took, where the budget left (less the reserve) holds them at their predicted time; then
        ``last`` is all of them fused around the one the verifier finds likeliest.
        ``rechecked``: None where not doubted, else whether the runs ran."""
        verifier = self.model.verifier
        if not self.recheck or verifier is None or self.rechecked is not None:
            return
        if self.stopped_by == "cancelled" or self.iteration == 0:
            return
        first = canonical_points(self.points[:1], self.pose_normalized[:1])
        doubt = float(verifier.scores(first)[0])
        if doubt >= 0.0:
            return
        self.rechecked = False
        k, card = self.recheck_runs, self.model.card
        size = _run_subset(card.points, self._min_points, len(self._cloud))
        load = _step_load(k, size, card.points)
        predicted = self.iteration * self.model.predicted_step_ms() * load + verifier.predicted_ms(
            k, size
        )
        if self._left_ms() < predicted:
            return
        rng = np.random.default_rng(self._seed + 1)
        x = np.stack(
            [self.normalization.apply(cap_points(self._cloud, size, rng)) for _ in range(k)]
        ).astype(np.float32)
        poses = np.tile(np.eye(4, dtype=np.float32), (k, 1, 1))
        poses[:, :3, :3] = viewing_axis_turns(k)
        deadline = self.started + self.budget_ms / 1e3
        for _ in range(self.iteration):
            slack = self._left_ms()
            with self.model.step_slot(max(slack, 0.0) / 1e3, deadline) as free:
                if slack <= 0 or not free or self._cancel.is_set():
                    return
                poses, _ = self.model.step(x, poses)
        scores = np.concatenate([[doubt], verifier.scores(canonical_points(x, poses))])
        runs = np.concatenate([self.pose_normalized[:1], poses])
        anchor = likeliest_run(scores)
        self.last = self._moved_to(fuse_poses(runs, card.symmetry, anchor=anchor))
        self.rechecked = True

    def _finish_verify(self) -> None:
        """``last`` fused anew around a run chosen by how right it looks: by the model's learned
        verifier where it has one (the run it finds likeliest; one call), else where the
        fusion's medoid does not hold its pose when knocked off by the probe turns and the
        network steps back, the firmest run (itnet.basin), where the budget left (less the
        reserve) holds the verifier's call or the probes' steps at their predicted time.
        ``verified``: they ran."""
        if not self.verify or self.verified is not None:
            return
        self.verified = False
        if self.stopped_by == "cancelled" or self.iteration == 0:
            return
        verifier, symmetry = self.model.verifier, self.model.card.symmetry
        if verifier is not None:
            slack = self._left_ms()
            if slack < verifier.predicted_ms(*self.points.shape[:2]) or self._cancel.is_set():
                return
            scores = verifier.scores(canonical_points(self.points, self.pose_normalized))
            anchor = likeliest_run(scores)
        else:
            turns = probe_turns(PROBE_DEG)
            predicted = PROBE_STEPS * self.model.predicted_step_ms() * self._load * len(turns)
            slack = self._left_ms() - predicted
            if slack < 0:
                return
            deadline = self.started + self.budget_ms / 1e3
            with self.model.step_slot(slack / 1e3, deadline) as free:
                if not free or self._cancel.is_set():
                    return
                drift = basin_drift(
                    lambda x, pose: self.model.step(x, pose)[0],
                    self.points,
                    self.pose_normalized,
                    turns,
                    PROBE_STEPS,
                )
            anchor = firm_anchor(drift, medoid_index(self.pose_normalized, symmetry))
        self.last = self._moved_to(fuse_poses(self.pose_normalized, symmetry, anchor=anchor))
        self.verified = True

    def _finish_mirror(self) -> None:
        """``last`` finished by the card's mirror planes, in order, as many as the budget left
        (less the reserve) holds at a plane's predicted time. ``mirror_planes``: the planes
        that finished it."""
        if not self.mirror or self.mirror_planes is not None:
            return
        self.mirror_planes = []
        if self.stopped_by == "cancelled" or self.iteration == 0:
            return
        pose = self.last.pose_normalized.astype(np.float64)
        points = self.points[0].astype(np.float64)
        for plane in self.model.card.mirror_planes:
            if self._left_ms() < self.model.predicted_mirror_ms():
                break
            start = time.perf_counter()
            pose = mirror_finished(points, pose, [plane])
            if self.up is not None:  # a mirror plane's refinement may tilt it
                pose = held_upright(pose, self.up)
            self.model.record_mirror_ms((time.perf_counter() - start) * 1e3)
            self.mirror_planes.append(plane)
        if self.mirror_planes:
            self.last = self._moved_to(pose)

    @property
    def mirrored(self) -> bool | None:
        """Once finished: whether a mirror plane finished the pose (None before, or when off)."""
        return None if self.mirror_planes is None else bool(self.mirror_planes)

    def _moved_to(self, pose_normalized: NDArray) -> Estimate:
        """The estimate at ``pose_normalized`` (4, 4), its update measured from ``last``'s pose
        (the fused ensemble's step, the mirror's correction)."""
        d = pose_normalized @ invert_rigid(self.last.pose_normalized.astype(np.float64))
        return self._estimate(
            pose_normalized.astype(np.float32),
            float(rotation_angle_deg(d[:3, :3])),
            math.hypot(float(d[0, 3]), float(d[1, 3]), float(d[2, 3])),
        )

    def _converged_or(self, estimate: Estimate) -> Estimate:
        """``estimate``, after marking the run converged if its update was below the tolerance."""
        if (
            estimate.update_rotation_deg < self.converge[0]
            and estimate.update_translation < self.converge[1] * self.normalization.scale
            and self.iteration < self.max_iterations
        ):
            self.stopped_by = "converged"
        return estimate

    def _stop_reason_before_step(self) -> str | None:
        if self._cancel.is_set():
            return "cancelled"
        if self.iteration >= self.max_iterations:
            return "max_iterations"
        if self._slack_ms() < 0:
            return "budget"
        return None

    def _left_ms(self) -> float:
        """Budget left, less the reserve for the reply (negative: overrun)."""
        return self.budget_ms - self.reserve_ms - self.elapsed_ms()

    def _slack_ms(self) -> float:
        """Budget left after the predicted next step and the reserve (negative: the step would
        overrun)."""
        predicted = max(self.model.predicted_step_ms() * self._load, self._last_step_ms)
        return self._left_ms() - predicted

    def _estimate(
        self, pose_normalized: NDArray, rotation_deg: float, translation: float
    ) -> Estimate:
        return Estimate(
            self.iteration,
            pose_normalized,
            self.normalization,
            self.elapsed_ms(),
            rotation_deg,
            translation * self.normalization.scale,
        )

    def poses(self) -> NDArray[np.float64]:
        """T_canonical_from_input (B, 4, 4), input units: the pose so far from every start."""
        poses = self.pose_normalized.astype(np.float64)
        return np.stack([pose_from_normalized(p, n) for p, n in zip(poses, self.normalizations)])

    def run_to_end(self) -> Estimate:
        """Consume the run; the final estimate (iteration 0 = centred cloud, the start rotation)."""
        for _ in self:
            pass
        return self.last

    def result(self) -> dict:
        """The final reply: pose fields, iterations, stop reason, elapsed time."""
        return {
            **pose_fields(self.last.pose),
            "iterations": self.iteration,
            "stopped_by": self.stopped_by,
            "elapsed_ms": round(self.elapsed_ms(), 3),
            "model": self.model.card.name,
            **({"ensemble": self.ensemble} if self.ensemble > 1 else {}),
            **(
                {"mirror": self.mirrored, "mirror_planes": list(self.mirror_planes or [])}
                if self.mirror
                else {}
            ),
            **({"verified": bool(self.verified)} if self.verify else {}),
            **({"rechecked": self.rechecked} if self.rechecked is not None else {}),
            **({"centre": bool(self.centred)} if self.centre else {}),
            **(
                {"centre_viewpoint": self.centred_by_viewpoint}
                if self.centre and self.viewpoint is not None
                else {}
            ),
            **({"centre_up": self.centred_by_up} if self.centre and self.up is not None else {}),
            **({"up": [round(float(v), 6) for v in self.up]} if self.up is not None else {}),
        }
