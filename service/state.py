"""What one app holds while it serves: settings, loaded models, metrics, the concurrency gate.

``start_run`` turns a decoded request into an :class:`AnytimeRun` (the only anytime loop) or a
:class:`ServiceError` that says what is wrong.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial

from numpy.typing import ArrayLike

from itnet.service.decode import Decoder, shorten
from itnet.service.draining import StreamDrain
from itnet.service.engine import AnytimeRun, BadCloudError
from itnet.service.errors import ServiceError
from itnet.service.guards.byte_budget import ByteBudget
from itnet.service.handback import HandbackTimer
from itnet.service.metrics import Metrics
from itnet.service.recognition import AUTO, RecognisedRun, recognise, second_look_deadline
from itnet.service.runtime import (
    LoadedClassifier,
    LoadedModel,
    LoadedVerifier,
    ModelLoadError,
    attach_verifiers,
    load_all,
    load_beside,
    pair_classifiers,
)
from itnet.service.schemas import EstimateParams
from itnet.service.settings import Settings

log = logging.getLogger("itnet.service")
PREFERRED_DEFAULT = "chair"


class ConcurrencyGate:
    """Counts estimates in flight; beyond ``limit`` a request is refused at once with a 503.

    Used from the event loop only (acquire and release never race), so a plain counter suffices.
    """

    def __init__(self, limit: int, retry_after_s: int, metrics: Metrics) -> None:
        self.limit, self.retry_after_s, self.metrics = limit, retry_after_s, metrics
        self.active = 0

    def check(self) -> None:
        """The 503 now if every slot is taken (a slot is taken with ``slot``)."""
        if self.active >= self.limit:
            raise ServiceError(
                503,
                "overloaded",
                f"the server is busy ({self.active} estimates running, the limit is "
                f"{self.limit}); retry in {self.retry_after_s} s",
                headers={"Retry-After": str(self.retry_after_s)},
            )

    @contextmanager
    def slot(self) -> Iterator[None]:
        self.check()
        self.active += 1
        self.metrics.in_flight.inc()
        try:
            yield
        finally:
            self.active -= 1
            self.metrics.in_flight.dec()


@dataclass
class ServiceState:
    settings: Settings
    metrics: Metrics
    models: dict[str, LoadedModel] = field(default_factory=dict)
    load_error: str | None = None
    classifier: LoadedClassifier | None = None  # the category classifier (model "auto")

    def __post_init__(self) -> None:
        limits = self.settings.limits
        self.gate = ConcurrencyGate(
            limits.max_concurrent_requests, limits.retry_after_s, self.metrics
        )
        self.handback = HandbackTimer()
        # Request bytes held at once (service/guards/byte_budget.py), and decoding under the limits.
        self.buffers = ByteBudget(limits.max_buffered_bytes)
        self.decoder = Decoder(limits.max_points, limits.heavy_json_bytes,
                               limits.json_parse_lanes, limits.retry_after_s)  # fmt: skip
        self.drain = StreamDrain()

    def load(self) -> None:
        """Load the models of ``settings.model_dir`` unless given; a failure leaves the app
        alive but not ready (``/readyz`` says why)."""
        if not self.models:
            try:
                self.models, self.classifier = load_all(
                    self.settings.model_dir,
                    self.settings.threads,
                    self.settings.warm_up,
                    self.settings.concurrent_steps,
                )
            except ModelLoadError as err:
                self.load_error = str(err)
                log.error("no model loaded: %s", err)
                return
        elif self.classifier is None:  # pose models handed in (itnet serve): what lies beside
            folder, loaded = (
                self.settings.model_dir,
                frozenset(m.path.resolve() for m in self.models.values()),
            )
            classifiers: list[LoadedClassifier] = []
            verifiers: list[LoadedVerifier] = []
            try:
                classifiers, verifiers = load_beside(
                    folder, self.settings.threads, self.settings.warm_up, loaded
                )
            except ModelLoadError as err:
                log.error("no classifier or verifier loaded (model 'auto' is off): %s", err)
            try:
                self.classifier = pair_classifiers(classifiers, folder)
            except ModelLoadError as err:
                log.error("no classifier loaded (model 'auto' is off): %s", err)
            try:  # and the verifiers of their categories
                attach_verifiers(self.models, verifiers, folder)
            except ModelLoadError as err:
                log.error("no verifier loaded (verify runs the probes): %s", err)
        wanted = self.settings.default_model
        if wanted is not None and wanted not in self.models:
            self.load_error = (
                f"the default model {wanted!r} is not loaded (loaded: {', '.join(self.models)})"
            )
            log.error("%s", self.load_error)

    @property
    def ready(self) -> bool:
        return bool(self.models) and self.load_error is None

    def default_model_name(self) -> str | None:
        """Settings' default, else 'chair' if loaded, else the only model, else None."""
        if self.settings.default_model is not None:
            return self.settings.default_model
        if PREFERRED_DEFAULT in self.models:
            return PREFERRED_DEFAULT
        return next(iter(self.models)) if len(self.models) == 1 else None

    def model(self, name: str | None) -> LoadedModel:
        """The named (or default) model, or a 503/404/422 that says what is available."""
        if not self.ready:
            raise ServiceError(503, "not_ready", f"no model is loaded: {self.load_error}")
        available = ", ".join(sorted(self.models))
        if name is None:
            name = self.default_model_name()
            if name is None:
                raise ServiceError(
                    422, "invalid_request", f"name a model: there is no default among {available}"
                )
        if name not in self.models:
            raise ServiceError(
                404, "unknown_model", f"unknown model {shorten(name)} (loaded: {available})"
            )
        return self.models[name]

    def start_run(
        self,
        points: ArrayLike,
        params: EstimateParams,
        arrived: float | None = None,
        reserve_ms: float = 0.0,
    ) -> AnytimeRun:
        """Validate and normalise the cloud and set up the run (CPU: call from a worker thread).
        The budget counts from ``arrived`` (``time.perf_counter()`` when the request came in).
        The card's default ensemble is fitted to the budget as shared with the estimates in
        flight (each model's step slots serve them all)."""
        auto = params.model == AUTO and AUTO not in self.models
        model = None if auto else self.model(params.model)
        limits = self.settings.limits
        if params.budget_ms > limits.max_budget_ms:
            raise ServiceError(
                422,
                "invalid_request",
                f"budget_ms {params.budget_ms:g} is over the limit of {limits.max_budget_ms:g} ms",
            )
        if params.max_iterations is not None and params.max_iterations > limits.max_iterations:
            raise ServiceError(
                422,
                "invalid_request",
                f"max_iterations {params.max_iterations} is over the limit of "
                f"{limits.max_iterations}",
            )
        recognition = None
        if model is None:  # classify first (its time counts: the run's clock started at arrival)
            if not self.ready:
                raise ServiceError(503, "not_ready", f"no model is loaded: {self.load_error}")
            recognition, model = recognise(
                self.classifier, self.models, points, limits.engine_limits(), params.units,
                looks=params.ensemble or 1, up=params.up,
                second_looks=self.settings.classify_second_looks,
                deadline=second_look_deadline(
                    time.perf_counter() if arrived is None else arrived, params.budget_ms
                ),
            )  # fmt: skip
        model.relax_step_ms()  # a step-time estimate inflated by a past burst must not stick
        iterations = params.max_iterations or min(
            model.card.recommended_iterations, limits.max_iterations
        )
        try:
            make = AnytimeRun if recognition is None else partial(RecognisedRun, recognition)
            return make(
                model,
                points,
                budget_ms=params.budget_ms,
                max_iterations=iterations,
                limits=limits.engine_limits(),
                started=arrived,
                reserve_ms=reserve_ms,
                ensemble=params.ensemble,
                mirror=params.mirror,
                verify=params.verify,
                recheck=params.recheck,
                centre=params.centre,
                viewpoint=params.viewpoint,
                up=params.up,
                sharing=self.gate.active / max(1, model.concurrent_steps),
            )
        except BadCloudError as err:
            raise ServiceError(422, "bad_cloud", str(err)) from None
