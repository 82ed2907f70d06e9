"""What one app holds while it serves: settings, loaded models, metrics, the concurrency gate.

``start_run`` turns a decoded request into an :class:`AnytimeRun` (the only anytime loop) or a
:class:`ServiceError` that says what is wrong.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from numpy.typing import ArrayLike

from itnet.pose.admission import Admission, DeliveryLimit
from itnet.pose.catalog import Catalog
from itnet.pose.errors import PoseError
from itnet.pose.loop import AnytimeRun
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import (
    LoadedClassifier,
    LoadedModel,
    LoadedVerifier,
    ModelLoadError,
    attach_verifiers,
    load_all,
    load_beside,
    pair_classifiers,
)
from itnet.pose.shared_work import SharedWork
from itnet.service.decode import Decoder
from itnet.service.draining import StreamDrain
from itnet.service.errors import ServiceError
from itnet.service.guards.byte_budget import ByteBudget
from itnet.service.handback import HandbackTimer
from itnet.service.metrics import Metrics
from itnet.service.settings import Settings

log = logging.getLogger("itnet.service")


class ConcurrencyGate:
    """Counts estimates in flight; beyond ``limit``, or beyond what the admission now serves
    in full (``DeliveryLimit``), a request is refused at once with a 503, before its body.

    Used from the event loop only (acquire and release never race), so a plain counter suffices.
    """

    def __init__(
        self,
        limit: int,
        retry_after_s: int,
        metrics: Metrics,
        delivery: DeliveryLimit | None = None,
    ) -> None:
        self.limit, self.retry_after_s, self.metrics = limit, retry_after_s, metrics
        self.delivery = delivery
        self.active = 0

    def current_limit(self) -> int:
        """Estimates admitted at once now: the configured limit, or fewer where the machine
        lately served fewer in full."""
        return self.limit if self.delivery is None else min(self.limit, self.delivery.allowed())

    def refusal(self) -> ServiceError | None:
        """The 503 a request gets now, or None where a slot is free (taken with ``slot``)."""
        limit = self.current_limit()
        if self.active < limit:
            return None
        said = "" if limit == self.limit else f", {limit} served in full now"
        return ServiceError(
            503,
            "overloaded",
            f"the server is busy ({self.active} estimates running, the limit is "
            f"{self.limit}{said}); retry in {self.retry_after_s} s",
            headers={"Retry-After": str(self.retry_after_s)},
        )

    def check(self) -> None:
        """Raise the 503 now if every slot is taken."""
        refused = self.refusal()
        if refused is not None:
            raise refused

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
        self._catalog: Catalog | None = None
        self._catalog_key: tuple[int, int, int] | None = None
        limits = self.settings.limits
        # the runs admitted at once: at most the gate's, fewer while the machine serves fewer
        # (with several worker processes, what the others admitted counts too)
        self.admission = Admission(limits.retry_after_s, limits.max_concurrent_requests,
                                   SharedWork.from_env())  # fmt: skip
        self.gate = ConcurrencyGate(
            limits.max_concurrent_requests, limits.retry_after_s, self.metrics,
            self.admission.delivery,
        )  # fmt: skip
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
                    self.settings.runtime_options(),
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

    @property
    def catalog(self) -> Catalog:
        """The loaded models as the pose pipeline sees them (rebuilt when the models change)."""
        key = (id(self.models), len(self.models), id(self.classifier))
        if self._catalog is None or self._catalog_key != key:
            self._catalog = Catalog(
                self.models, self.classifier, self.settings.default_model,
                self.settings.limits.engine_limits(), self.settings.classify_second_looks,
                self.admission,
            )  # fmt: skip
            self._catalog_key = key
        return self._catalog

    def default_model_name(self) -> str | None:
        """Settings' default, else 'chair' if loaded, else the only model, else None."""
        return self.catalog.default_name()

    def model(self, name: str | None) -> LoadedModel:
        """The named (or default) model, or a 503/404/422 that says what is available."""
        with self._replying():
            return self.catalog.model(name)

    def start_run(
        self,
        points: ArrayLike,
        request: PoseRequest,
        arrived: float | None = None,
        reserve_ms: float = 0.0,
        decode_ms: float | None = None,
    ) -> AnytimeRun:
        """Resolve the model (classifying for ``auto``), plan the request and set up its run
        (CPU: call from a worker thread). The budget counts from ``arrived``
        (``time.perf_counter()`` when the request came in); ``decode_ms``: how long its body took
        to decode (a body whose decoding alone spends the budget is refused as unmeetable, not
        as an overload). Raises ServiceError."""
        with self._replying():
            return self.catalog.start(points, request, arrived, reserve_ms, decode_ms)

    @contextmanager
    def serving(self, run: AnytimeRun) -> Iterator[None]:
        """Hold ``run`` among the admitted while it runs (``Catalog.serving``), then check that
        it served a pose; a refusal (its work does not fit, no step fit its budget) is raised as
        the ServiceError to answer with."""
        with self._replying(), self.catalog.serving(run):
            yield

    @contextmanager
    def _replying(self) -> Iterator[None]:
        """Not ready: the 503; what the pose pipeline refuses: its ServiceError."""
        if not self.ready:
            raise ServiceError(503, "not_ready", f"no model is loaded: {self.load_error}")
        try:
            yield
        except PoseError as err:
            raise ServiceError.of(err) from None
