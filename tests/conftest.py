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
from numpy.typing import NDArray

from itnet.pose.runtime import LoadedModel

# Servers started by the tests (in process and as subprocesses) leave the garbage collector alone:
# gc.freeze() would keep every object of the pytest process alive. tests/service/test_gc.py
# checks the freeze itself.
os.environ.setdefault("ITNET_GC_FREEZE", "false")


def make_tiny_net(  # type: ignore[no-untyped-def]
    seed: int = 0, point_channels: tuple[int, ...] = (16, 32, 64), rotation: str = "quaternion"
):
    """A small ITNet with random weights and random BatchNorm statistics (eval mode)."""
    import torch

    from itnet.model.network import ITNet, NetworkConfig

    torch.manual_seed(seed)
    config = NetworkConfig(point_channels=point_channels, head_channels=(32, 16), rotation=rotation)
    net = ITNet(config)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.normal_(0, 0.1)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.normal_(1, 0.1)
                m.bias.normal_(0, 0.1)
        net.regressor.out.weight.normal_(0, 0.01)  # small but not the identity
    return net.eval()


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
def tiny_model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with ``tiny.onnx`` (model name 'tiny', category 'chair', 256 points)."""
    from itnet.export.onnx_export import export_step
    from itnet.model_card import ModelCard

    folder = tmp_path_factory.mktemp("models")
    card = ModelCard(name="tiny", category="chair", points=256, recommended_iterations=5)
    export_step(make_tiny_net(), card, folder / "tiny.onnx")
    return folder


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
