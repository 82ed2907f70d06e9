"""Shared fixtures: a tiny random IT-Net exported to ONNX (fast, and not the identity)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from factory import export_tiny, make_tiny_net
from numpy.typing import NDArray

from itnet.pose.runtime import LoadedModel

# The page tests' fixtures (tests/web, tests/scene): a real server and a headless browser page.
pytest_plugins = ["tests.page_fixtures"]

# Servers started by the tests (in process and as subprocesses) leave the garbage collector alone:
# gc.freeze() would keep every object of the pytest process alive. tests/service/test_gc.py
# checks the freeze itself.
os.environ.setdefault("ITNET_GC_FREEZE", "false")


@pytest.fixture
def tiny_net():  # type: ignore[no-untyped-def]
    """The network inside ``tiny_model_dir`` (same seed), in torch. (A fixture rather than an
    import: with several conftest.py files, ``from conftest import`` finds whichever came last.)"""
    return make_tiny_net()


@pytest.fixture(scope="session")
def make_net() -> Callable[..., Any]:
    """``make_tiny_net`` itself, for fixtures elsewhere that export a variant of it."""
    return make_tiny_net


@pytest.fixture(scope="session")
def export_model() -> Callable[..., Path]:
    """``export_tiny(card, path, seed=0, point_channels=..., rotation=...)``: the tiny network's
    step with ``card``, exported once per network (tests/factory.py)."""
    return export_tiny


@pytest.fixture(scope="session")
def tiny_model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with ``tiny.onnx`` (model name 'tiny', category 'chair', 256 points)."""
    from itnet.model_card import ModelCard

    folder = tmp_path_factory.mktemp("models")
    card = ModelCard(name="tiny", category="chair", points=256, recommended_iterations=5)
    export_tiny(card, folder / "tiny.onnx")
    return folder


@pytest.fixture(scope="module")
def model(tiny_model_dir: Path) -> LoadedModel:
    """The model of ``tiny_model_dir``, loaded with one thread."""
    from itnet.pose.runtime import load_model

    return load_model(tiny_model_dir / "tiny.onnx", threads=1)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@dataclass
class SlowModel(LoadedModel):
    """A model with ``delay_s`` of sleep per step (stands in for a big model), counting the steps
    it has run."""

    delay_s: float = 0.03
    steps: int = 0

    def step(
        self, points: NDArray[np.float32], pose: NDArray[np.float32]
    ) -> tuple[NDArray, NDArray]:
        time.sleep(self.delay_s)
        self.steps += 1
        return super().step(points, pose)


def _slow_copy(model: LoadedModel, delay_s: float, concurrent_steps: int = 8) -> SlowModel:
    """Its steps sleep rather than compute, so several may run at once without sharing cores
    (a real model on a small machine gets ``cores // threads`` step slots)."""
    return SlowModel(
        card=model.card,
        path=model.path,
        session=model.session,
        delay_s=delay_s,
        concurrent_steps=concurrent_steps,
    )


@pytest.fixture(scope="session")
def slow_copy() -> Callable[..., SlowModel]:
    """``slow_copy(model, delay_s, concurrent_steps=8)``: a copy whose steps sleep ``delay_s``."""
    return _slow_copy
