"""Fixtures of the hardening tests: settings with small limits, the tiny model slowed down, a
live server around it (see hardening_helpers.py)."""

from __future__ import annotations

import gc
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hardening_helpers import LIMITS, SERVER, LiveServer, cloud, live_server

from itnet.pose.runtime import LoadedModel, load_models
from itnet.service.gc_tuning import freeze_startup_objects
from itnet.service.settings import Settings


@pytest.fixture(scope="session", autouse=True)
def _startup_objects_out_of_gc(tiny_model_dir: Path) -> Iterator[None]:
    """These tests time a server that runs inside the test process, which has imported torch
    (for the tiny model's export): a full garbage collection of that many objects stalls every
    thread for hundreds of ms, the pause that ``ITNET_GC_FREEZE`` removes from the service. Do
    what the service does: freeze what exists once everything is imported."""
    freeze_startup_objects()
    yield
    gc.unfreeze()


@pytest.fixture(scope="module")
def settings(tiny_model_dir: Path) -> Settings:
    return Settings(model_dir=tiny_model_dir, limits=LIMITS, server=SERVER, warm_up=False)


@pytest.fixture(scope="module")
def tiny(settings: Settings) -> LoadedModel:
    (model,) = load_models(settings.model_dir, threads=1).values()
    return model


@pytest.fixture
def slow(tiny: LoadedModel, slow_copy: Callable[..., Any]) -> Any:
    """The tiny model at 20 ms a step (a fresh copy per test: its step counter starts at 0)."""
    model = slow_copy(tiny, delay_s=0.02)
    model.warm_up(runs=2)
    return model


@pytest.fixture
def slow_server(settings: Settings, slow: LoadedModel) -> Iterator[LiveServer]:
    with live_server(settings, {"tiny": slow}) as server:
        yield server


@pytest.fixture(scope="session")
def points() -> list[list[float]]:
    return cloud().tolist()  # type: ignore[no-any-return]


@pytest.fixture(scope="session")
def heavy_model_dir(
    export_model: Callable[..., Path], tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """A random IT-Net whose per-point layers are wide (64, 384, 4096): about 10 ms a step on
    the tests' 300-point cloud with one thread, so a request can still be running when the
    signal comes. (Padding the cloud would not do: the runtime feeds a small cloud whole.)"""
    from itnet.model_card import ModelCard

    folder = tmp_path_factory.mktemp("heavy")
    card = ModelCard(name="tiny", category="chair", points=1024, recommended_iterations=5)
    export_model(card, folder / "tiny.onnx", point_channels=(64, 384, 4096))
    return folder
