"""Loading shipped IT-Net step graphs into onnxruntime, with their model cards.

Session options for small machines: ``intra_op_num_threads`` threads (default 2), no thread
spinning (spinning threads steal the CPU from the web server on 2 cores), sequential execution,
all graph optimisations.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import onnxruntime as ort
from numpy.typing import NDArray

from itnet.model_card import METADATA_KEY, ModelCard


class ModelLoadError(RuntimeError):
    """A model file is missing, corrupt, or has no itnet model card."""


def default_model_dir() -> Path:
    """The models shipped inside the package (no network, no configuration)."""
    return Path(str(resources.files("itnet") / "models"))


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
    _estimated_at: float = field(default=0.0, repr=False)  # perf_counter of step_ms's last update

    def step(
        self, points: NDArray[np.float32], pose: NDArray[np.float32]
    ) -> tuple[NDArray, NDArray]:
        """points (B, N, 3), pose (B, 4, 4) float32 -> (pose_next, delta), each (B, 4, 4)."""
        pose_next, delta = self.session.run(None, {"points": points, "pose": pose})
        return pose_next, delta

    def record_step_ms(self, ms: float, weight: float = 0.2) -> None:
        with self._lock:
            self.step_ms = ms if self.step_ms == 0 else (1 - weight) * self.step_ms + weight * ms
            self._estimated_at = time.perf_counter()

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

    def warm_up(self, runs: int = 5) -> None:
        """Run a few steps so the first request does not pay for lazy initialisation, and seed
        the step-time estimate."""
        rng = np.random.default_rng(0)
        x = rng.normal(size=(1, self.card.points, 3)).astype(np.float32)
        pose = np.eye(4, dtype=np.float32)[None]
        for _ in range(runs):
            start = time.perf_counter()
            self.step(x, pose)
            ms = (time.perf_counter() - start) * 1e3
            self.record_step_ms(ms, weight=0.5)
            self.baseline_ms = ms if self.baseline_ms == 0 else min(self.baseline_ms, ms)


def read_card(session: ort.InferenceSession, path: Path) -> ModelCard:
    meta = session.get_modelmeta().custom_metadata_map
    if METADATA_KEY not in meta:
        raise ModelLoadError(f"{path}: not an itnet model (no '{METADATA_KEY}' metadata)")
    return ModelCard.model_validate_json(meta[METADATA_KEY])


def load_model(path: Path, threads: int = 2, warm_up: bool = True) -> LoadedModel:
    """Load one .onnx step graph. Raises ModelLoadError with the reason."""
    if not path.is_file():
        raise ModelLoadError(f"{path}: model file not found")
    try:
        session = ort.InferenceSession(
            str(path), session_options(threads), providers=["CPUExecutionProvider"]
        )
    except Exception as err:  # onnxruntime raises its own exception types for corrupt graphs
        raise ModelLoadError(f"{path}: cannot load the ONNX graph ({err})") from err
    names = [i.name for i in session.get_inputs()]
    if names != ["points", "pose"]:
        raise ModelLoadError(f"{path}: expected inputs ['points', 'pose'], found {names}")
    model = LoadedModel(read_card(session, path), path, session)
    if warm_up:
        model.warm_up()
    return model


def load_models(directory: Path, threads: int = 2, warm_up: bool = True) -> dict[str, LoadedModel]:
    """Every .onnx model in a directory, by card name. Raises ModelLoadError if there is none."""
    paths = sorted(directory.glob("*.onnx")) if directory.is_dir() else []
    if not paths:
        raise ModelLoadError(f"{directory}: no .onnx models found")
    models = [load_model(p, threads, warm_up) for p in paths]
    return {m.card.name: m for m in models}
