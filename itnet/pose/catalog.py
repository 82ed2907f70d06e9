"""``Catalog``: the models one process serves, and the one way a request becomes a run.

    catalog = Catalog.load()                               # the shipped models, warmed up
    run = catalog.start(cloud, PoseRequest(budget_ms=20))  # model resolved, planned, ready
    for estimate in run: ...                               # or run.run_to_end(); run.result()

Every path calls ``start``: the HTTP route and the WebSocket, ``itnet pose``, alignment (each
cloud's pose), batch poses, scenes and the benchmarks. It resolves the request's model (by name,
the default, or ``auto``: classified first, on the request's clock), plans the request once
(``itnet.pose.plan``) and hands the plan to the one anytime loop (``itnet.pose.loop``).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from numpy.typing import ArrayLike

from itnet.pose.admission import Admission
from itnet.pose.cloud import Limits, cut_out
from itnet.pose.errors import PoseError, UnknownModelError
from itnet.pose.loop import AnytimeRun
from itnet.pose.plan import PosePlan, plan
from itnet.pose.recognition import AUTO, SECOND_LOOKS, Recognition, recognise, second_look_deadline
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import LoadedClassifier, LoadedModel, default_model_dir, load_all

PREFERRED_DEFAULT = "chair"


def shorten(text: str, limit: int = 64) -> str:
    """``text`` as ``repr`` shows it, cut to about ``limit`` characters (never echo 1 MB)."""
    return repr(text) if len(text) <= limit else f"{text[:limit]!r}... ({len(text)} characters)"


@dataclass
class Catalog:
    """Pose models by name, the category classifier behind ``model: "auto"`` (None: off), the
    default model's name (None: 'chair' where loaded, else the only model), the request limits,
    the looks of an unsure classification's second opinion, and the admission of the runs posed
    at once (``itnet.pose.admission``)."""

    models: dict[str, LoadedModel]
    classifier: LoadedClassifier | None = None
    default: str | None = None
    limits: Limits = field(default_factory=Limits)
    second_looks: int = SECOND_LOOKS
    admission: Admission = field(default_factory=Admission)

    @classmethod
    def load(cls, model_dir: Path | None = None, threads: int = 2, warm_up: bool = True,
             **kwargs: object) -> Catalog:  # fmt: skip
        """Every model of ``model_dir`` (default: the shipped ones), warmed up. Raises
        ``itnet.pose.runtime.ModelLoadError``."""
        models, classifier = load_all(model_dir or default_model_dir(), threads, warm_up)
        return cls(models, classifier, **kwargs)  # type: ignore[arg-type]

    def default_name(self) -> str | None:
        """The configured default, else 'chair' if loaded, else the only model, else None."""
        if self.default is not None:
            return self.default
        if PREFERRED_DEFAULT in self.models:
            return PREFERRED_DEFAULT
        return next(iter(self.models)) if len(self.models) == 1 else None

    def model(self, name: str | None) -> LoadedModel:
        """The named (or default) pose model; UnknownModelError (404) or PoseError (422) saying
        what is loaded."""
        available = ", ".join(sorted(self.models))
        name = self.default_name() if name is None else name
        if name is None:
            raise PoseError(f"name a model: there is no default among {available}")
        if name not in self.models:
            raise UnknownModelError(f"unknown model {shorten(name)} (loaded: {available})")
        return self.models[name]

    def is_auto(self, name: str | None) -> bool:
        return name == AUTO and AUTO not in self.models

    def plan(
        self, points: ArrayLike, request: PoseRequest, started: float | None = None
    ) -> tuple[PosePlan, Recognition | None]:
        """The request's plan on its model; with ``auto``, the cloud classified first (its time
        counts from ``started``) and the recognition with it. Raises PoseError subclasses."""
        recognition, spent_ms = None, 0.0
        if self.is_auto(request.model):
            started = time.perf_counter() if started is None else started
            recognition, model = recognise(
                self.classifier, self.models, points, self.limits, request.units,
                looks=request.ensemble or 1, up=request.up, second_looks=self.second_looks,
                deadline=second_look_deadline(started, request.budget_ms),
            )  # fmt: skip
            spent_ms = recognition.elapsed_ms
        else:
            model = self.model(request.model)
        return plan(model, request, self.limits, spent_ms), recognition

    def start(
        self,
        points: ArrayLike,
        request: PoseRequest,
        started: float | None = None,
        reserve_ms: float = 0.0,
        decode_ms: float | None = None,
    ) -> AnytimeRun:
        """The request's run on its cloud (a cut-out's floor and walls taken away where ``up``
        is given: ``itnet.pose.cloud.cut_out``), ready to iterate (``started``: its clock, default now;
        ``reserve_ms``: kept back for handing the reply back; ``decode_ms``: how long decoding
        the request took, default all the time since ``started``). Raises PoseError
        subclasses."""
        started = time.perf_counter() if started is None else started
        points, stripped = cut_out(points, request, self.limits)
        planned, recognition = self.plan(points, request, started)
        planned.model.relax_step_ms()  # a step time inflated by a past burst must not stick
        return AnytimeRun(planned, points, started, reserve_ms, recognition, decode_ms, stripped)

    @contextmanager
    def serving(self, *runs: AnytimeRun) -> Iterator[None]:
        """Hold ``runs`` (one request's) among the admitted while they run, then check that each
        served a pose. Raises OverloadedError (the work admitted leaves them no room, or no step
        fit a budget) or BudgetTooSmallError (one step is longer than the budget, or, with no
        other run admitted, the request's own decoding alone passed its budget)."""
        alone = self.admission.running == 0
        with self.admission.admit(*runs):
            yield
        for run in runs:
            run.check_served(alone)

    def pose(self, points: ArrayLike, request: PoseRequest | None = None,
             started: float | None = None) -> dict:  # fmt: skip
        """The finished pose of one cloud (N, 3) as a reply's dict (``T_canonical_from_input``,
        both quaternions, ``iterations``, ``stopped_by``, ...), admitted beside the runs this
        catalog poses at once, its budget counted from ``started`` (default now); never a start
        without a step. Raises PoseError subclasses."""
        return self.pose_together([self.start(points, request or PoseRequest(), started)])[0]

    def pose_together(self, runs: list[AnytimeRun]) -> list[dict]:
        """The finished poses of ``runs`` (started by ``start``: one request's clouds, such as an
        alignment's two), admitted together as one request, run one after the other on their
        shared clock (in a thread each, on two cores, they took longer: docs/align.md). Raises
        PoseError subclasses, those of the first run that served no pose first."""
        with self.serving(*runs):
            for run in runs:
                run.run_to_end()
        return [run.result() for run in runs]
