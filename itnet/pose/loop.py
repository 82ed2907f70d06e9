"""The anytime loop: the only place that iterates IT-Net steps. Every path consumes it.

    run = AnytimeRun(plan(model, PoseRequest(budget_ms=50)), cloud)
    for estimate in run:          # one Estimate per iteration, as soon as it exists
        ...
    run.result()                  # the finished pose, how it was reached, why it stopped

Per request: validate the cloud, normalise it (``itnet.preprocess``: centroid, RMS radius), give
each run its points (the model's count, seeded; fused runs each their own subset), then loop:
predict the next step's time, stop if it would overrun the budget, run the step (every run in
one call), compose, fuse, hold upright, and yield the pose. After the last step the plan's
finishing stages (``itnet.pose.stages``) run in order, each where its predicted time still fits;
the streamed estimates are the network's, ``result()`` the finished pose.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.basin import canonical_points
from itnet.floor_and_walls import Stripped
from itnet.fusion import fuse_poses
from itnet.geometry import invert_rigid, rotation_angle_deg
from itnet.pose.cloud import normalization_of, validate_cloud
from itnet.pose.errors import BudgetTooSmallError, OverloadedError
from itnet.pose.plan import PosePlan
from itnet.pose.reply import Estimate, pose_fields
from itnet.preprocess import cap_points, pose_from_normalized
from itnet.upright import held_upright

T = TypeVar("T")


class AnytimeRun(Iterator[Estimate]):
    """One request's anytime estimation; iterate it for the estimates. Thread-safe ``cancel``.

    ``started``: the budget's clock (a ``time.perf_counter()`` value, e.g. when the request
    arrived, so that decoding and queueing count), default now. ``reserve_ms``: kept back from
    the budget for handing the reply back after the finish (never more than half of it).
    ``recognition``: what ``model: "auto"`` recognised (its reply and first stream message).
    ``stripped``: the floor and walls taken from the cloud sent (``points`` is what was left)."""

    def __init__(
        self,
        plan: PosePlan,
        points: ArrayLike,
        started: float | None = None,
        reserve_ms: float = 0.0,
        recognition: object | None = None,
        decode_ms: float | None = None,
        stripped: Stripped | None = None,
    ) -> None:
        self.started = time.perf_counter() if started is None else started
        # how long the request's own decoding took (default: all the time since it started)
        self.decode_ms = (
            (time.perf_counter() - self.started) * 1e3 if decode_ms is None else decode_ms
        )
        self.plan, self.model, self.recognition = plan, plan.model, recognition
        self.stripped = stripped
        self.cloud = validate_cloud(points, plan.limits)
        self.reserve_ms = min(max(0.0, reserve_ms), plan.budget_ms / 2)
        # The whole cloud sets the centre and scale; each run sees its own seeded draw of at
        # most the model's count (fused runs: a subset each).
        self.normalization = normalization_of(self.cloud)
        rng = np.random.default_rng(plan.seed)
        size = plan.run_points(len(self.cloud))
        draws = [cap_points(self.cloud, size, rng) for _ in range(plan.runs)]
        self.points = np.stack([self.normalization.apply(d) for d in draws]).astype(np.float32)
        self.pose_normalized = np.tile(np.eye(4, dtype=np.float32), (plan.runs, 1, 1))
        self.pose_normalized[:, :3, :3] = plan.starts
        self._size = size
        # coarse first steps see the first points of each run's draw: a random subset where the
        # draw is one, else (a small cloud whole, in its order) a seeded shuffle of it
        if plan.coarse_at and len(self.cloud) <= size:
            order = np.random.default_rng(plan.seed + 1).permutation(size)
            self.points = self.points[:, order]
        self.iteration = 0
        self.stopped_by: str | None = None
        self.last: Estimate = self._estimate(self.pose_normalized[0], 0.0, 0.0)
        self.finish_fields: dict = {}
        self.skipped: list[str] = []
        self._finished = False
        self._cancel = threading.Event()
        self._last_step_ms = 0.0
        # the network's work so far: points stepped, summed over runs and steps (stages too)
        self.point_steps = 0

    # -- the loop ------------------------------------------------------------------------------

    def __next__(self) -> Estimate:
        if self.stopped_by is None:
            self.stopped_by = self._stop_reason_before_step()
        if self.stopped_by is not None:
            self._finish()
            raise StopIteration
        stepping = self.plan.step_points(self.iteration, self._size)
        stepped = self.extra_step(self.points[:, :stepping], self.pose_normalized)
        if stepped is None:  # no step slot freed in time, or cancelled while waiting
            self.stopped_by = "cancelled" if self._cancel.is_set() else "budget"
            self._finish()
            raise StopIteration
        self.pose_normalized, delta = stepped
        if self.plan.up is not None and self.iteration >= self.plan.up_free:
            self.pose_normalized = held_upright(self.pose_normalized, self.plan.up).astype(
                np.float32
            )
        self.iteration += 1
        if self.iteration == self.plan.halving_at:
            self._halve()
        if self.plan.fuse:
            self.last = self._moved_to(fuse_poses(self.pose_normalized, self.model.card.symmetry))
        else:
            self.last = self._update_of(self.pose_normalized[0], delta[0])
        return self._converged_or(self.last)

    def _halve(self) -> None:
        """Successive halving: keep the ``plan.halving`` runs the category's verifier finds
        likeliest (one call over every run), drop the rest; where the verifier's call would not
        fit the budget, every run goes on."""
        verifier, keep = self.model.verifier, self.plan.halving_keep
        if verifier is None or keep >= len(self.points):
            return
        if (
            self.left_ms()
            < verifier.predicted_ms(*self.points.shape[:2]) + self.predicted_step_ms()
        ):
            return
        scores = verifier.scores(canonical_points(self.points, self.pose_normalized))
        kept = np.sort(np.argsort(-np.asarray(scores), kind="stable")[:keep])
        self.points, self.pose_normalized = self.points[kept], self.pose_normalized[kept]

    @property
    def runs(self) -> int:
        """The runs stepping now: the plan's, or those kept after the halving."""
        return len(self.points)

    def extra_step(self, points: NDArray, poses: NDArray) -> tuple[NDArray, NDArray] | None:
        """One network step of ``points`` (B, N, 3) from ``poses`` (B, 4, 4), batched with the
        steps of the other runs in flight, ending inside the budget (less the reserve) -> the
        poses after it and the step's updates, each (B, 4, 4); None where it could not, or the
        run is cancelled. Stages call it too."""
        if self._cancel.is_set():
            return None
        start = time.perf_counter()
        stepped = self.model.batched_step(points, poses, self._latest())
        self._last_step_ms = (time.perf_counter() - start) * 1e3  # the wait included
        if stepped is not None:
            self.point_steps += points.shape[0] * points.shape[1]
        return stepped  # a step done counts, cancelled or not

    def extra_call(self, work: Callable[[], T], predicted_ms: float) -> T | None:
        """``work()`` with a step slot to itself, where it can start and still end inside the
        budget at ``predicted_ms``; None where it cannot, or the run is cancelled."""
        if self._cancel.is_set():
            return None
        ran, result = self.model.batcher.exclusive(work, self._latest() - predicted_ms / 1e3)
        return result if ran and not self._cancel.is_set() else None

    def _latest(self) -> float:
        """When the budget, less the reserve, ends (a ``time.perf_counter()`` value)."""
        return self.started + (self.plan.budget_ms - self.reserve_ms) / 1e3

    def _finish(self) -> None:
        """After the last step (once): a run stopped within the card's free steps is stood up,
        then the plan's stages run in order, each where its predicted time fits (none after a
        cancel or before any step)."""
        if self._finished:
            return
        self._finished = True
        ran = self.iteration > 0 and self.stopped_by != "cancelled"
        if ran and self.plan.up is not None and self.iteration <= self.plan.up_free:
            self.last = self._moved_to(held_upright(self.last.pose_normalized, self.plan.up))
        for stage in self.plan.stages:
            if not ran or self._cancel.is_set():
                self.finish_fields.update(stage.not_run(self))
                continue
            if self.left_ms() < stage.predicted_ms(self):
                self.skipped.append(stage.name)
                self.finish_fields.update(stage.not_run(self))
                continue
            finish = stage.apply(self)
            if finish.pose is not None:
                self.last = self._moved_to(np.asarray(finish.pose))
            self.finish_fields.update(finish.fields)

    def cancel(self) -> None:
        self._cancel.set()

    # -- time ----------------------------------------------------------------------------------

    def elapsed_ms(self) -> float:
        return (time.perf_counter() - self.started) * 1e3

    def left_ms(self) -> float:
        """Budget left, less the reserve for the reply (negative: overrun)."""
        return self.plan.budget_ms - self.reserve_ms - self.elapsed_ms()

    def predicted_step_ms(self) -> float:
        """The next step of this run's runs: the model's running prediction (or the last step's
        time, if longer)."""
        points = self.plan.step_points(self.iteration, self._size)
        return max(self.model.run_step_ms(self.runs, points), self._last_step_ms)

    @property
    def needed_iterations(self) -> int:
        """The iterations this run needs: its plan's, up to the model's recommended ones (a
        request for more takes those as the budget allows)."""
        return min(self.plan.max_iterations, self.model.card.recommended_iterations)

    def needed_work_ms(self) -> float:
        """The steps this run still needs at the model's current step time: its plan's, up to
        the model's recommended iterations (a request for more takes those as the budget
        allows). Runs are admitted by it (``itnet.pose.admission``)."""
        return self.plan.work_ms(self.needed_iterations, self._size, self._one_run_ms,
                                 start=self.iteration, now=self.runs)  # fmt: skip

    def _one_run_ms(self, points: int) -> float:
        return self.model.run_step_ms(1, points)

    def idle_iterations(self) -> int:
        """The iterations an idle machine gives this run: as many of its needed ones as fit
        its budget, less the reserve and its decoding, at the step time measured at load (at
        least 1)."""
        available = self.plan.budget_ms - self.reserve_ms - self.decode_ms
        one = self.plan.idle_run_ms
        fits = 0
        while (
            fits < self.needed_iterations
            and self.plan.work_ms(fits + 1, self._size, one) <= available
        ):
            fits += 1
        return max(1, fits)

    def _slack_ms(self) -> float:
        """Budget left after the predicted next step and the reserve (negative: the step would
        overrun)."""
        return self.left_ms() - self.predicted_step_ms()

    def _stop_reason_before_step(self) -> str | None:
        if self._cancel.is_set():
            return "cancelled"
        if self.iteration >= self.plan.max_iterations:
            return "max_iterations"
        if self._slack_ms() < 0:
            return "budget"
        return None

    # -- estimates -----------------------------------------------------------------------------

    def _update_of(self, pose: NDArray, d: NDArray) -> Estimate:
        """The estimate at ``pose`` (4, 4), its update the network's ``d`` (4, 4), measured in
        scalar math (numpy's per-call cost is the loop's)."""
        cos = (float(d[0, 0]) + float(d[1, 1]) + float(d[2, 2]) - 1.0) / 2.0
        rotation = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
        return self._estimate(
            pose, rotation, math.hypot(float(d[0, 3]), float(d[1, 3]), float(d[2, 3]))
        )

    def _moved_to(self, pose_normalized: NDArray) -> Estimate:
        """The estimate at ``pose_normalized`` (4, 4), its update measured from ``last``'s pose
        (the fused runs' step, a stage's correction)."""
        d = pose_normalized @ invert_rigid(self.last.pose_normalized.astype(np.float64))
        return self._estimate(
            pose_normalized.astype(np.float32),
            float(rotation_angle_deg(d[:3, :3])),
            math.hypot(float(d[0, 3]), float(d[1, 3]), float(d[2, 3])),
        )

    def _converged_or(self, estimate: Estimate) -> Estimate:
        """``estimate``, after marking the run converged if its update was below the tolerance."""
        rotation, translation = self.plan.converge
        if (
            estimate.update_rotation_deg < rotation
            and estimate.update_translation < translation * self.normalization.scale
            and self.iteration < self.plan.max_iterations
        ):
            self.stopped_by = "converged"
        return estimate

    def _estimate(
        self, pose_normalized: NDArray, rotation_deg: float, translation: float
    ) -> Estimate:
        return Estimate(self.iteration, pose_normalized, self.normalization, self.elapsed_ms(),
                        rotation_deg, translation * self.normalization.scale)  # fmt: skip

    # -- results -------------------------------------------------------------------------------

    def poses(self) -> NDArray[np.float64]:
        """T_canonical_from_input (runs, 4, 4), input units: every run's own pose so far."""
        poses = self.pose_normalized.astype(np.float64)
        return np.stack([pose_from_normalized(p, self.normalization) for p in poses])

    def run_to_end(self) -> Estimate:
        """Consume the run; the final (finished) estimate."""
        for _ in self:
            pass
        return self.last

    def result(self) -> dict:
        """The final reply: the finished pose, iterations, stop reason, elapsed time, the runs
        fused, what each finishing stage did and which ones the budget skipped."""
        recognised = {} if self.recognition is None else self.recognition.as_dict()  # type: ignore[attr-defined]
        return {
            **pose_fields(self.last.pose),
            "iterations": self.iteration,
            "stopped_by": self.stopped_by,
            "elapsed_ms": round(self.elapsed_ms(), 3),
            "model": self.model.card.name,
            "ensemble": self.plan.runs,
            **self.finish_fields,
            "skipped": list(self.skipped),
            **(
                {"up": [round(float(v), 6) for v in self.plan.up]}
                if self.plan.up is not None
                else {}
            ),
            **({"runs": self.poses().tolist()} if self.plan.request.runs else {}),
            **({"stripped": self.stripped.as_dict()} if self.stripped is not None else {}),
            **recognised,
        }

    def check_served(self, alone: bool = False) -> None:
        """Where the budget ran out before the first step, the start is no pose and must never be
        handed back as one: BudgetTooSmallError (422) where one step of this plan takes longer
        than the whole budget on an idle machine, or where the run was ``alone`` (no other run
        admitted beside it) and its own decoding (``decode_ms``) took at least half the budget
        and left no room for one idle step: retrying the same body cannot succeed. (Decoding
        that took less, yet left no room for a step, is a busy moment: a retry may succeed.)
        Else OverloadedError (503: the machine was too busy, or the request too slow to
        arrive)."""
        if self.iteration > 0 or self.stopped_by != "budget":
            return
        step_ms = self.plan.first_step_ms(len(self.cloud))  # on an idle machine: not the load
        if step_ms > self.plan.budget_ms:
            raise BudgetTooSmallError(
                f"budget_ms {self.plan.budget_ms:g} is below one step of model "
                f"{self.model.card.name!r} (about {step_ms:.3g} ms here): no pose fits it"
            )
        if alone and _unmeetable(self.decode_ms, step_ms, self.plan.budget_ms):
            raise BudgetTooSmallError(
                f"decoding this request took {self.decode_ms:.1f} ms of its "
                f"budget_ms {self.plan.budget_ms:g}, and one step takes about {step_ms:.3g} ms: "
                "no pose fits it; send the cloud as binary float32 (Content-Type: "
                "application/octet-stream, the parameters in the query), which decodes in a "
                "fraction of the time, or give a larger budget"
            )
        raise OverloadedError(
            f"no step of model {self.model.card.name!r} fit in budget_ms {self.plan.budget_ms:g}: "
            f"{self.elapsed_ms():.0f} ms had passed since the request arrived (receiving it, "
            "waiting for the busy machine); retry, or give a larger budget"
        )

    def category_message(self) -> dict:
        """The stream's first message where the model was recognised: the category, before the
        first estimate."""
        assert self.recognition is not None
        return {"type": "category", "model": self.model.card.name, **self.recognition.as_dict()}  # type: ignore[attr-defined]


def _unmeetable(decode_ms: float, step_ms: float, budget_ms: float) -> bool:
    """Whether a body whose decoding took ``decode_ms`` can never be posed within
    ``budget_ms``: its decoding takes half the budget or more, and with one step of
    ``step_ms`` (on an idle machine) it passes the budget."""
    return decode_ms >= budget_ms / 2 and decode_ms + step_ms > budget_ms
