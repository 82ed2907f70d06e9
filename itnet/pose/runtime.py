"""Loading shipped IT-Net step graphs into onnxruntime, with their model cards.

Session options for small machines: ``intra_op_num_threads`` threads (default 2), no thread
spinning (spinning threads steal the CPU from the web server on 2 cores), sequential execution,
all graph optimisations.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import onnxruntime as ort
from numpy.typing import NDArray

from itnet.centre import CentreCorrection
from itnet.model_card import METADATA_KEY, ClassifierCard, ModelCard, VerifierCard, parse_card
from itnet.pose.step_batcher import StepBatcher


class ModelLoadError(RuntimeError):
    """A model file is missing, corrupt, or has no itnet model card."""


def default_model_dir() -> Path:
    """The models shipped inside the package (no network, no configuration)."""
    return Path(str(resources.files("itnet") / "models"))


def warm_batches(recommended_ensemble: int, usual: tuple[int, ...] = (2, 4, 8)) -> list[int]:
    """The batch sizes a pose model is warmed up at besides 1: the usual ensembles and the
    card's recommended one with its halvings (what a default ensemble that fits its budget
    runs: ``itnet.pose.plan.fitting_ensemble``)."""
    sizes, k = set(usual), recommended_ensemble
    while k > 1:
        sizes.add(k)
        k //= 2
    return sorted(sizes)


def default_concurrent_steps(threads: int) -> int:
    """Steps of one model that may run at once: as many as the cores hold (cores // threads)."""
    return max(1, (os.cpu_count() or 1) // max(1, threads))


def session_options(threads: int = 2, spinning: bool = False) -> ort.SessionOptions:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    options.log_severity_level = 3
    return options


@dataclass
class LoadedModel:
    """An onnxruntime session of one step graph, its card, and its measured step time."""

    card: ModelCard
    path: Path
    session: ort.InferenceSession
    step_ms: float = 0.0  # running estimate of one step at card.points (EWMA)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    baseline_ms: float = 0.0  # fastest warm-up step: the step time without contention
    idle_ms: float = 0.0  # median warm-up step: what plans are made with (load-independent)
    _estimated_at: float = field(default=0.0, repr=False)  # perf_counter of step_ms's last update
    concurrent_steps: int = 1  # graph calls that may run at once; the others wait for a slot
    batch_jobs: int = 64  # steps of different runs one call may hold (1: no batching)
    recent_window_s: float = 2.0  # how far back predicted_step_ms looks
    # running estimate of one mirror plane's refinement (itnet.mirror; EWMA): measured by
    # warm_up, else a conservative start (3-5 ms on 2 cores for a 256-point subset)
    mirror_ms: float = 10.0
    # the learned verifier of the card's category, where the model folder has one (load_all):
    # fused runs' verify anchors on the run it finds likeliest instead of running the probes
    verifier: LoadedVerifier | None = None

    def __post_init__(self) -> None:
        self.batcher = StepBatcher(self.step, self.run_step_ms, self.concurrent_steps,
                                   self.batch_jobs, self._record_call)  # fmt: skip
        # The card's centre corrections, parsed once: a bad one fails the load, not a request.
        self.centre = self._centre_correction("centre_correction", viewpoint=False)
        self.centre_viewpoint = self._centre_correction(
            "centre_correction_viewpoint", viewpoint=True
        )
        self.centre_up = self._centre_correction("centre_correction_up", viewpoint=False)
        self.centre_up_viewpoint = self._centre_correction(
            "centre_correction_up_viewpoint", viewpoint=True
        )
        self._recent: deque[tuple[float, float]] = deque(maxlen=64)  # (perf_counter, ms)
        self._high: tuple[float, float, float] | None = None  # (quantile ms, when, quantile)

    def _centre_correction(self, field_name: str, viewpoint: bool) -> CentreCorrection | None:
        """The card's ``field_name``, parsed and of the kind it must be (taking the sensor's
        direction or not), or None where the card has none. Raises ModelLoadError."""
        data = getattr(self.card, field_name)
        if data is None:
            return None
        try:
            correction = CentreCorrection.from_dict(data)
        except (KeyError, TypeError, ValueError) as err:
            raise ModelLoadError(f"{self.path}: {field_name}: {err}") from None
        if correction.uses_viewpoint != viewpoint:
            needs = "takes the sensor's direction" if viewpoint else "takes no viewpoint"
            raise ModelLoadError(f"{self.path}: {field_name} must be a correction that {needs}")
        return correction

    def batched_step(
        self, points: NDArray[np.float32], pose: NDArray[np.float32], latest: float
    ) -> tuple[NDArray, NDArray] | None:
        """One step of ``points`` (B, N, 3) from ``pose`` (B, 4, 4), in one call with the steps
        of the other runs in flight (``itnet.pose.step_batcher``), ending by ``latest`` (a
        ``time.perf_counter()`` value) -> (pose_next, delta); None where it cannot."""
        return self.batcher.step(points, pose, latest)

    def _record_call(self, ms: float, runs: int, points: int) -> None:
        """A call's measured time, folded into the estimate of one run's step."""
        self.record_step_ms(ms / self.step_load(runs, points))

    def step(
        self, points: NDArray[np.float32], pose: NDArray[np.float32]
    ) -> tuple[NDArray, NDArray]:
        """points (B, N, 3), pose (B, 4, 4) float32 -> (pose_next, delta), each (B, 4, 4)."""
        pose_next, delta = self.session.run(None, {"points": points, "pose": pose})
        return pose_next, delta

    def record_mirror_ms(self, ms: float, weight: float = 0.3) -> None:
        """Fold a measured mirror refinement's time (one plane's) into its estimate."""
        with self._lock:
            self.mirror_ms = (1 - weight) * self.mirror_ms + weight * ms

    def predicted_mirror_ms(self) -> float:
        """What the next mirror refinement may take, a plane: its running estimate with a margin
        (its time scatters with the cloud's shape)."""
        return 1.5 * self.mirror_ms

    def record_step_ms(self, ms: float, weight: float = 0.2, at: float | None = None) -> None:
        """Fold a measured step time into the estimates (``at``: its perf_counter, now)."""
        with self._lock:
            self.step_ms = ms if self.step_ms == 0 else (1 - weight) * self.step_ms + weight * ms
            self._estimated_at = time.perf_counter() if at is None else at
            self._recent.append((self._estimated_at, ms))
            self._high = None  # the quantile is recomputed on the next prediction

    def predicted_step_ms(self, quantile: float = 0.9) -> float:
        """What the next step may take: the running estimate, or the ``quantile`` of the steps
        of the last ``recent_window_s`` if higher. On a machine whose load comes and goes, step
        times scatter; the mean alone lets one step in a few overrun the budget.

        Called before every step: the quantile is cached until the next measurement, or for at
        most 50 ms (so that steps leaving the window are noticed)."""
        with self._lock:
            now = time.perf_counter()
            if self._high is None or now - self._high[1] > 0.05 or self._high[2] != quantile:
                since = now - self.recent_window_s
                recent = sorted(ms for at, ms in self._recent if at >= since)
                high = recent[min(len(recent) - 1, int(quantile * len(recent)))] if recent else 0.0
                self._high = (high, now, quantile)
            return max(self.step_ms, self._high[0])

    def relax_step_ms(self, half_life_s: float = 1.0) -> float:
        """Let a stale step-time estimate relax toward ``baseline_ms`` (half-life ``half_life_s``
        since its last update) and return it. A burst of concurrent requests inflates the
        estimate; without this, budgets smaller than the inflated value would never run a step
        again, so would never re-measure it. Called by the service before each run."""
        with self._lock:
            now = time.perf_counter()
            if 0 < self.baseline_ms < self.step_ms and self._estimated_at > 0:
                excess = self.step_ms - self.baseline_ms
                decay = 0.5 ** ((now - self._estimated_at) / half_life_s)
                self.step_ms = self.baseline_ms + excess * decay
            self._estimated_at = now
            return self.step_ms

    def run_step_ms(self, runs: int, points: int, idle: bool = False) -> float:
        """One step of ``runs`` runs of ``points`` points each: the step time at the card's
        point count (``idle``: as measured at load; else the running prediction) times the load,
        about proportional to the points, with a floor for the fixed part."""
        one = self.idle_ms if idle else self.predicted_step_ms()
        return one * self.step_load(runs, points)

    def step_load(self, runs: int, points: int) -> float:
        """A step's cost in steps of one run of the card's point count."""
        return max(runs * points / self.card.points, 0.25)

    def warm_up(self, runs: int = 7) -> None:
        """Run steps at every batch size a plan may use, so the first request does not pay for
        onnxruntime's lazy initialisation (it plans each new batch size on its first run), and
        measure the idle step time plans are made with; where the card declares mirror planes,
        seed the mirror refinement's estimate too (all its rounds, a plane)."""
        rng = np.random.default_rng(0)
        x = rng.normal(size=(1, self.card.points, 3)).astype(np.float32)
        pose = np.eye(4, dtype=np.float32)[None]
        times = []
        for _ in range(runs):
            start = time.perf_counter()
            self.step(x, pose)
            times.append((time.perf_counter() - start) * 1e3)
        for ms in times[1:]:
            self.record_step_ms(ms, weight=0.5)
        self.baseline_ms = min(times)
        self.idle_ms = float(np.median(times[1:]))
        kept = (self.card.halving[1],) if self.card.halving else ()
        coarse = (self.card.coarse_steps[1],) if self.card.coarse_steps else ()
        for batch in warm_batches(self.card.recommended_ensemble, (2, 4, 8, *kept)):
            points = int(0.8 * self.card.points)  # a fused run's subset (itnet.pose.plan)
            # and the coarse first steps' points, where the card has them
            for n in sorted({points, self.card.points, *coarse}):
                for _ in range(2):
                    self.step(np.repeat(x[:, :n], batch, axis=0), np.repeat(pose, batch, axis=0))
        if self.card.mirror:
            from itnet.mirror import mirror_refined

            mirror_times = []
            for _ in range(2):
                start = time.perf_counter()
                mirror_refined(x[0].astype(np.float64), np.eye(4), settled=0.0)
                mirror_times.append((time.perf_counter() - start) * 1e3)
            self.mirror_ms = min(mirror_times)


def read_card(
    session: ort.InferenceSession, path: Path
) -> ModelCard | ClassifierCard | VerifierCard:
    """The card of a pose step, a classifier or a verifier (its ``kind`` says which)."""
    meta = session.get_modelmeta().custom_metadata_map
    if METADATA_KEY not in meta:
        raise ModelLoadError(f"{path}: not an itnet model (no '{METADATA_KEY}' metadata)")
    try:
        return parse_card(meta[METADATA_KEY])
    except ValueError as err:  # pydantic's ValidationError: a corrupt or foreign card
        raise ModelLoadError(f"{path}: unreadable model card ({err})") from None


@dataclass
class LoadedClassifier:
    """The category classifier (``model: "auto"``): normalised points -> class probabilities."""

    card: ClassifierCard
    path: Path
    session: ort.InferenceSession
    # the upright classifier (its card's ``upright``) beside this one, for clouds whose up is
    # known (``itnet.pose.recognition``); None: those are classified by this one
    upright: LoadedClassifier | None = None

    def probabilities(self, points: NDArray[np.float32]) -> NDArray[np.float32]:
        """Normalised points (B, N, 3) float32 -> probabilities (B, C), classes as card.classes."""
        (probs,) = self.session.run(None, {"points": points})
        return np.asarray(probs)

    def warm_up(self, runs: int = 3) -> None:
        x = np.random.default_rng(0).normal(size=(1, self.card.points, 3)).astype(np.float32)
        for _ in range(runs):
            self.probabilities(x)


WARM_RUNS = 8  # a verifier's warm-up call: as many runs as the usual ensemble


@dataclass
class LoadedVerifier:
    """A category's learned verifier (``model/verifier.py``): each run's points where its pose
    puts them -> the logit of the pose being right."""

    card: VerifierCard
    path: Path
    session: ort.InferenceSession
    score_ms: float = 5.0  # one call of WARM_RUNS runs of card.points, measured by warm_up

    def scores(self, points: NDArray[np.float32]) -> NDArray[np.float32]:
        """Canonical-frame points (K, N, 3) float32 -> logits (K,)."""
        (logits,) = self.session.run(None, {"points": np.ascontiguousarray(points, np.float32)})
        return np.asarray(logits).reshape(-1)

    def predicted_ms(self, runs: int, points: int) -> float:
        """One call's time for ``runs`` runs of ``points`` points each (it scales with both)."""
        return self.score_ms * runs * points / (WARM_RUNS * self.card.points)

    def warm_up(self, runs: int = 3) -> None:
        shape = (WARM_RUNS, self.card.points, 3)
        x = np.random.default_rng(0).normal(size=shape).astype(np.float32)
        times = []
        for _ in range(runs):
            start = time.perf_counter()
            self.scores(x)
            times.append((time.perf_counter() - start) * 1e3)
        self.score_ms = min(times)


# onnxruntime's execution providers for each device a setting may name, best first.
PROVIDERS = {
    "cpu": ["CPUExecutionProvider"],
    "cuda": ["CUDAExecutionProvider", "CPUExecutionProvider"],
    "tensorrt": ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"],
}


@dataclass(frozen=True)
class RuntimeOptions:
    """Where the graphs run and how steps share calls: ``provider`` (``cpu``, ``cuda``,
    ``tensorrt``: onnxruntime's execution providers; the GPU ones need onnxruntime-gpu) and
    ``batch_jobs`` (steps of different runs one call may hold; 1: none shared)."""

    provider: str = "cpu"
    batch_jobs: int = 64

    def providers(self) -> list[str]:
        """The execution providers to ask for; ModelLoadError where the device is unknown or
        this onnxruntime build lacks it."""
        if self.provider not in PROVIDERS:
            raise ModelLoadError(
                f"unknown provider {self.provider!r} (one of {', '.join(PROVIDERS)})"
            )
        wanted, available = PROVIDERS[self.provider], ort.get_available_providers()
        if wanted[0] not in available:
            raise ModelLoadError(
                f"provider {self.provider!r} needs {wanted[0]}, which this onnxruntime build "
                f"lacks (it has {', '.join(available)}; install onnxruntime-gpu for a GPU)"
            )
        return [p for p in wanted if p in available]


def _session(path: Path, threads: int, options: RuntimeOptions) -> ort.InferenceSession:
    if not path.is_file():
        raise ModelLoadError(f"{path}: model file not found")
    providers = options.providers()
    try:
        return ort.InferenceSession(str(path), session_options(threads), providers=providers)
    except Exception as err:  # onnxruntime raises its own exception types for corrupt graphs
        raise ModelLoadError(f"{path}: cannot load the ONNX graph ({err})") from err


def load_any(
    path: Path,
    threads: int = 2,
    warm_up: bool = True,
    concurrent_steps: int | None = None,
    options: RuntimeOptions = RuntimeOptions(),
) -> LoadedModel | LoadedClassifier | LoadedVerifier:
    """One .onnx file: a pose step (see :func:`load_model`), the category classifier or a
    verifier, as its card says. Raises ModelLoadError with the reason."""
    session = _session(path, threads, options)
    card = read_card(session, path)
    if isinstance(card, ModelCard):
        return load_model(path, threads, warm_up, concurrent_steps, session, options)
    names = [i.name for i in session.get_inputs()]
    if names != ["points"]:
        raise ModelLoadError(f"{path}: a {card.kind} takes ['points'], found {names}")
    loaded: LoadedClassifier | LoadedVerifier
    if isinstance(card, VerifierCard):
        loaded = LoadedVerifier(card, path, session)
    else:
        loaded = LoadedClassifier(card, path, session)
    if warm_up:
        loaded.warm_up()
    return loaded


def load_model(
    path: Path,
    threads: int = 2,
    warm_up: bool = True,
    concurrent_steps: int | None = None,
    session: ort.InferenceSession | None = None,
    options: RuntimeOptions = RuntimeOptions(),
) -> LoadedModel:
    """Load one .onnx step graph. Raises ModelLoadError with the reason (a classifier is not a
    step graph). ``concurrent_steps`` defaults to :func:`default_concurrent_steps`."""
    session = session or _session(path, threads, options)
    card = read_card(session, path)
    if not isinstance(card, ModelCard):
        raise ModelLoadError(f"{path}: a {card.kind}, not a pose step graph")
    names = [i.name for i in session.get_inputs()]
    if names != ["points", "pose"]:
        raise ModelLoadError(f"{path}: expected inputs ['points', 'pose'], found {names}")
    steps = concurrent_steps or default_concurrent_steps(threads)
    # An int8 graph quantizes each call's activations as a whole (DynamicQuantizeLinear): a
    # run's step would then depend on the steps it shares a call with. Only float graphs share.
    shares = card.precision != "int8"
    jobs = options.batch_jobs if shares else 1
    model = LoadedModel(card, path, session, concurrent_steps=steps, batch_jobs=jobs)
    if warm_up:
        model.warm_up()
    return model


def load_models(
    directory: Path, threads: int = 2, warm_up: bool = True, concurrent_steps: int | None = None
) -> dict[str, LoadedModel]:
    """Every pose model (.onnx) in a directory, by card name. Raises ModelLoadError if there is
    none. The category classifier, if there, is skipped (:func:`load_all` gives it)."""
    return load_all(directory, threads, warm_up, concurrent_steps)[0]


def load_all(
    directory: Path,
    threads: int = 2,
    warm_up: bool = True,
    concurrent_steps: int | None = None,
    options: RuntimeOptions = RuntimeOptions(),
) -> tuple[dict[str, LoadedModel], LoadedClassifier | None]:
    """(pose models by card name, the category classifier or None) of a directory; an upright
    classifier rides on the other as its ``upright``. Raises ModelLoadError if there is no pose
    model, or more than one classifier of a kind."""
    paths = sorted(directory.glob("*.onnx")) if directory.is_dir() else []
    loaded = [load_any(p, threads, warm_up, concurrent_steps, options) for p in paths]
    models = {m.card.name: m for m in loaded if isinstance(m, LoadedModel)}
    if not models:
        raise ModelLoadError(f"{directory}: no .onnx models found")
    attach_verifiers(models, [m for m in loaded if isinstance(m, LoadedVerifier)], directory)
    classifiers = [m for m in loaded if isinstance(m, LoadedClassifier)]
    return models, pair_classifiers(classifiers, directory)


def attach_verifiers(
    models: dict[str, LoadedModel], verifiers: list[LoadedVerifier], directory: Path
) -> None:
    """Give each pose model the verifier of its card's category. Raises ModelLoadError for two
    verifiers of one category."""
    by_category: dict[str, LoadedVerifier] = {}
    for verifier in verifiers:
        other = by_category.setdefault(verifier.card.category, verifier)
        if other is not verifier:
            raise ModelLoadError(
                f"{directory}: two verifiers of {verifier.card.category} "
                f"({other.path.name}, {verifier.path.name})"
            )
    for model in models.values():
        model.verifier = by_category.get(model.card.category)


def pair_classifiers(
    classifiers: list[LoadedClassifier], directory: Path
) -> LoadedClassifier | None:
    """A directory's classifiers -> the one for any orientation, with the upright one (if any)
    beside it; None without classifiers. Raises ModelLoadError for two of a kind, or an upright
    classifier alone (a cloud without up would have nothing to classify it)."""
    kinds: dict[bool, LoadedClassifier] = {}
    for c in classifiers:
        if c.card.upright in kinds:
            kind = "upright classifier" if c.card.upright else "classifier"
            names = f"{kinds[c.card.upright].path.name}, {c.path.name}"
            raise ModelLoadError(f"{directory}: more than one {kind} ({names})")
        kinds[c.card.upright] = c
    if True in kinds and False not in kinds:
        raise ModelLoadError(
            f"{directory}: an upright classifier ({kinds[True].path.name}) serves only beside "
            "the classifier for any orientation, and there is none"
        )
    if True in kinds and kinds[True].card.classes != kinds[False].card.classes:
        raise ModelLoadError(
            f"{directory}: the upright classifier's classes ({kinds[True].card.classes}) are not "
            f"the other's ({kinds[False].card.classes})"
        )
    if False in kinds:
        kinds[False].upright = kinds.get(True)
    return kinds.get(False)


def load_beside(
    directory: Path, threads: int = 2, warm_up: bool = True, skip: frozenset[Path] = frozenset()
) -> tuple[list[LoadedClassifier], list[LoadedVerifier]]:
    """The classifiers and the verifiers of a directory, in one pass (:func:`pair_classifiers`
    and :func:`attach_verifiers` put them to work). Files in ``skip`` (pose models already
    loaded) are not opened again; other pose steps are opened, read and dropped. Raises
    ModelLoadError for a file that does not load."""
    paths = sorted(directory.glob("*.onnx")) if directory.is_dir() else []
    found = [load_any(p, threads, warm_up=False) for p in paths if p.resolve() not in skip]
    beside = [f for f in found if isinstance(f, LoadedClassifier | LoadedVerifier)]
    for loaded in beside if warm_up else []:
        loaded.warm_up()
    return (
        [c for c in beside if isinstance(c, LoadedClassifier)],
        [v for v in beside if isinstance(v, LoadedVerifier)],
    )
