"""Finishing stages: what runs after the last step, in order, each only where the budget holds it.

A stage is one class with one interface (``Stage``), switched by the request field of its
``name`` (``true``, ``false``, or ``null`` for the card's default):

    default(model, request, runs)   on by default for this card and request?
    refusal(model, request, runs)   why a request that asks for it explicitly is refused, or None
    predicted_ms(run)               what it will cost now (the loop skips it where that does
                                    not fit the budget left)
    apply(run)                      -> Finish: the new normalised pose (or None) and what it adds
                                    to the reply
    not_run(run)                    what the reply says when it did not run

A stage sees the run through ``StageRun``: its points, its pose so far, its model and plan, the
time left, and a way to take extra network steps inside the budget. Nothing else of the loop.

``STAGES`` is their order: recheck (a doubted single run's second opinion), verify (fused runs
anchored on the likeliest), mirror (the category's mirror planes), centre (the object centre's
correction). A new finishing step is one class here and one field of ``PoseRequest``; every path
(HTTP, stream, CLI, alignment, batch, scenes) gets it through the plan.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

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
from itnet.geometry import viewing_axis_turns
from itnet.mirror import mirror_finished
from itnet.preprocess import cap_points
from itnet.upright import held_upright

if TYPE_CHECKING:
    from itnet.pose.request import PoseRequest
    from itnet.pose.runtime import LoadedModel
    from itnet.preprocess import Normalization

RECHECK_RUNS = 4  # runs a doubted single run is rechecked with, where the card gives none
CENTRE_MS = 0.2  # a centre correction's cost: one small linear map


@dataclass(frozen=True)
class Finish:
    """A stage's outcome: the new pose (normalised frame, 4x4; None: unchanged) and its reply
    fields."""

    pose: NDArray | None
    fields: dict = field(default_factory=dict)


T = TypeVar("T")


class StagePlan(Protocol):
    """What a stage reads of the run's plan."""

    @property
    def up(self) -> NDArray[np.float64] | None: ...  # the cloud's up, where the request gave one
    @property
    def viewpoint(self) -> NDArray[np.float64] | None: ...  # the sensor (cloud's frame, units)
    @property
    def seed(self) -> int: ...

    def subset_points(self, cloud_points: int) -> int: ...


class StagePose(Protocol):
    @property
    def pose_normalized(self) -> NDArray[np.float32]: ...  # (4, 4), the network's frame


class StageRun(Protocol):
    """What a stage sees of the run it finishes (``itnet.pose.loop.AnytimeRun`` is one)."""

    @property
    def model(self) -> LoadedModel: ...
    @property
    def plan(self) -> StagePlan: ...
    @property
    def cloud(self) -> NDArray: ...  # (N, 3) as sent, input units
    @property
    def normalization(self) -> Normalization: ...  # input units -> the network's frame
    @property
    def points(self) -> NDArray[np.float32]: ...  # (runs, P, 3) each run's subset, network frame
    @property
    def pose_normalized(self) -> NDArray[np.float32]: ...  # (runs, 4, 4) each run's pose so far
    @property
    def last(self) -> StagePose: ...  # the estimate so far (fused where runs are)
    @property
    def iteration(self) -> int: ...

    def left_ms(self) -> float: ...
    def predicted_step_ms(self) -> float: ...
    def extra_step(self, points: NDArray, poses: NDArray) -> tuple[NDArray, NDArray] | None: ...
    def extra_call(self, work: Callable[[], T], predicted_ms: float) -> T | None: ...


class Stage(Protocol):
    name: ClassVar[str]

    def default(self, model: LoadedModel, request: PoseRequest, runs: int) -> bool: ...
    def refusal(self, model: LoadedModel, request: PoseRequest, runs: int) -> str | None: ...
    def predicted_ms(self, run: StageRun) -> float: ...
    def apply(self, run: StageRun) -> Finish: ...
    def not_run(self, run: StageRun) -> dict: ...


class Recheck:
    """A single run that the category's learned verifier doubts (logit below 0) is rechecked:
    the card's ``recheck_runs`` runs from turned starts, each on its own subset, as many steps
    as the run took, where the budget holds them; then the fused pose of all of them, anchored
    on the likeliest (model/verifier.py; docs/models.md)."""

    name: ClassVar[str] = "recheck"

    def default(self, model: LoadedModel, request: PoseRequest, runs: int) -> bool:
        return model.card.recheck_runs > 0 and model.verifier is not None and _plain(request, runs)

    def refusal(self, model: LoadedModel, request: PoseRequest, runs: int) -> str | None:
        if model.verifier is None:
            return f"model {model.card.name!r} has no verifier loaded: recheck needs one"
        if not _plain(request, runs):
            return "recheck is for a single run (no ensemble or up)"
        return None

    def predicted_ms(self, run: StageRun) -> float:
        assert run.model.verifier is not None
        return run.model.verifier.predicted_ms(1, run.points.shape[1])

    def apply(self, run: StageRun) -> Finish:
        verifier, card = run.model.verifier, run.model.card
        assert verifier is not None
        doubt = float(verifier.scores(canonical_points(run.points[:1], run.pose_normalized[:1]))[0])
        if doubt >= 0.0:
            return Finish(None)
        k = card.recheck_runs or RECHECK_RUNS
        size = run.plan.subset_points(len(run.cloud))
        predicted = run.iteration * run.model.run_step_ms(k, size) + verifier.predicted_ms(k, size)
        if run.left_ms() < predicted:
            return Finish(None, {"rechecked": False})
        rng = np.random.default_rng(run.plan.seed + 1)
        x = np.stack(
            [run.normalization.apply(cap_points(run.cloud, size, rng)) for _ in range(k)]
        ).astype(np.float32)
        poses = np.tile(np.eye(4, dtype=np.float32), (k, 1, 1))
        poses[:, :3, :3] = viewing_axis_turns(k)
        for _ in range(run.iteration):
            stepped = run.extra_step(x, poses)
            if stepped is None:
                return Finish(None, {"rechecked": False})
            poses = stepped[0]
        scores = np.concatenate([[doubt], verifier.scores(canonical_points(x, poses))])
        runs = np.concatenate([run.pose_normalized[:1], poses])
        fused = fuse_poses(runs, card.symmetry, anchor=likeliest_run(scores))
        return Finish(fused, {"rechecked": True})

    def not_run(self, run: StageRun) -> dict:
        return {}  # not doubted, as far as anyone knows


class Verify:
    """Fused runs anchored anew on the run that looks right: by the category's learned verifier
    where one is loaded (the run it finds likeliest; one call), else on the run that sits most
    firmly in its basin when knocked off by the probe turns (``itnet.basin``)."""

    name: ClassVar[str] = "verify"

    def default(self, model: LoadedModel, request: PoseRequest, runs: int) -> bool:
        return model.card.verify_fused and runs > 1 and self._can_hold_upright(model, request)

    def refusal(self, model: LoadedModel, request: PoseRequest, runs: int) -> str | None:
        if runs == 1:
            return "verify weighs fused runs against each other: it needs ensemble > 1"
        if not self._can_hold_upright(model, request):
            return (
                "verify with up needs the category's learned verifier (the probes knock runs "
                "held upright off their tilt)"
            )
        return None

    @staticmethod
    def _can_hold_upright(model: LoadedModel, request: PoseRequest) -> bool:
        """Whether fused runs of this request can be weighed: without up by either means, with
        up only by the learned verifier (the probes knock runs held upright off their tilt)."""
        return request.up is None or model.verifier is not None

    def predicted_ms(self, run: StageRun) -> float:
        verifier = run.model.verifier
        if verifier is not None:
            return verifier.predicted_ms(*run.points.shape[:2])
        return PROBE_STEPS * len(probe_turns(PROBE_DEG)) * run.predicted_step_ms()

    def apply(self, run: StageRun) -> Finish:
        verifier, symmetry = run.model.verifier, run.model.card.symmetry
        if verifier is not None:
            anchor = likeliest_run(
                verifier.scores(canonical_points(run.points, run.pose_normalized))
            )
        else:
            drift = run.extra_call(
                lambda: basin_drift(
                    lambda x, pose: run.model.step(x, pose)[0],
                    run.points,
                    run.pose_normalized,
                    probe_turns(PROBE_DEG),
                    PROBE_STEPS,
                ),
                self.predicted_ms(run),
            )
            if drift is None:
                return Finish(None, {"verified": False})
            anchor = firm_anchor(drift, medoid_index(run.pose_normalized, symmetry))
        return Finish(fuse_poses(run.pose_normalized, symmetry, anchor=anchor), {"verified": True})

    def not_run(self, run: StageRun) -> dict:
        return {"verified": False}


class Mirror:
    """The final pose finished by the card's mirror planes, in order, as many as the budget
    holds at a plane's predicted time (``itnet.mirror``)."""

    name: ClassVar[str] = "mirror"

    def default(self, model: LoadedModel, request: PoseRequest, runs: int) -> bool:
        return model.card.mirror and (runs == 1 or model.card.mirror_fused)

    def refusal(self, model: LoadedModel, request: PoseRequest, runs: int) -> str | None:
        if model.card.mirror:
            return None
        return (
            f"model {model.card.name!r} declares no mirror symmetry (its card has no "
            "mirror_planes): mirror cannot finish its poses"
        )

    def predicted_ms(self, run: StageRun) -> float:
        return run.model.predicted_mirror_ms()

    def apply(self, run: StageRun) -> Finish:
        pose = run.last.pose_normalized.astype(np.float64)
        points = run.points[0].astype(np.float64)
        planes: list[str] = []
        for k, plane in enumerate(run.model.card.mirror_planes):
            if k > 0 and run.left_ms() < self.predicted_ms(run):  # the loop checked the first
                break
            start = time.perf_counter()
            pose = mirror_finished(points, pose, [plane])
            if run.plan.up is not None:  # a mirror plane's refinement may tilt it
                pose = np.asarray(held_upright(pose, run.plan.up), dtype=np.float64)
            run.model.record_mirror_ms((time.perf_counter() - start) * 1e3)
            planes.append(plane)
        return Finish(pose if planes else None, {"mirror": bool(planes), "mirror_planes": planes})

    def not_run(self, run: StageRun) -> dict:
        return {"mirror": False, "mirror_planes": []}


class Centre:
    """The object centre finished by the model's correction (``itnet.centre``), the first the
    request and the card have of: the one that goes by the sensor's direction fitted on runs
    held upright (a request with up and a viewpoint), the one that goes by the sensor's
    direction (a viewpoint), the one fitted on runs held upright (up), the plain one."""

    name: ClassVar[str] = "centre"

    def default(self, model: LoadedModel, request: PoseRequest, runs: int) -> bool:
        return self._applies(model, request)

    def refusal(self, model: LoadedModel, request: PoseRequest, runs: int) -> str | None:
        if self._applies(model, request):
            return None
        return (
            f"model {model.card.name!r} has no centre correction (its card has no "
            "centre_correction"
            + ("" if request.viewpoint is None else " and no centre_correction_viewpoint")
            + ("" if request.up is None else " and no centre_correction_up")
            + "): centre cannot finish its poses"
        )

    @staticmethod
    def _applies(model: LoadedModel, request: PoseRequest) -> bool:
        return (
            model.centre is not None
            or (request.viewpoint is not None and model.centre_viewpoint is not None)
            or (request.up is not None and model.centre_up is not None)
            or (
                request.up is not None
                and request.viewpoint is not None
                and model.centre_up_viewpoint is not None
            )
        )

    def predicted_ms(self, run: StageRun) -> float:
        return CENTRE_MS

    def apply(self, run: StageRun) -> Finish:
        model, plan, norm = run.model, run.plan, run.normalization
        pose, points = run.last.pose_normalized.astype(np.float64), run.points[0]
        finished, by_viewpoint, by_up = None, False, False
        if plan.viewpoint is not None:
            viewpoint = (plan.viewpoint - norm.center) / norm.scale
            held = plan.up is not None and model.centre_up_viewpoint is not None
            correction = model.centre_up_viewpoint if held else model.centre_viewpoint
            if correction is not None:
                try:
                    finished = centre_finished(points, pose, correction, viewpoint)
                    by_viewpoint, by_up = True, held
                except ValueError:  # the viewpoint on the estimated centre: no direction
                    pass
        if finished is None and plan.up is not None and model.centre_up is not None:
            finished, by_up = centre_finished(points, pose, model.centre_up), True
        if finished is None and model.centre is not None:
            finished = centre_finished(points, pose, model.centre)
        return Finish(finished, self._fields(run, finished is not None, by_viewpoint, by_up))

    def not_run(self, run: StageRun) -> dict:
        return self._fields(run, False, False, False)

    @staticmethod
    def _fields(run: StageRun, centred: bool, by_viewpoint: bool, by_up: bool) -> dict:
        return {
            "centre": centred,
            **({"centre_viewpoint": by_viewpoint} if run.plan.viewpoint is not None else {}),
            **({"centre_up": by_up} if run.plan.up is not None else {}),
        }


def _plain(request: PoseRequest, runs: int) -> bool:
    """A single run, not held upright."""
    return runs == 1 and request.up is None


STAGES: tuple[Stage, ...] = (Recheck(), Verify(), Mirror(), Centre())
STAGE_NAMES: tuple[str, ...] = tuple(stage.name for stage in STAGES)
