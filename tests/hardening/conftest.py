"""Fixtures of the hardening tests: settings with small limits, the tiny model slowed down, a
live server around it (see hardening_helpers.py)."""

from __future__ import annotations

import gc
import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hardening_helpers import LIMITS, SERVER, LiveServer, card_of, cloud, live_server, with_card

from itnet.service.gc_tuning import freeze_startup_objects
from itnet.service.runtime import LoadedModel, load_model, load_models
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
def heavy_model_dir(tiny_model_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny model told to resample every cloud to 50,000 points: about 10 ms a step, so a
    request can still be running when the signal comes."""
    folder = tmp_path_factory.mktemp("heavy")
    card = {**card_of(tiny_model_dir / "tiny.onnx"), "points": 50_000}
    with_card(tiny_model_dir / "tiny.onnx", folder / "tiny.onnx", json.dumps(card))
    assert load_model(folder / "tiny.onnx", warm_up=False).card.points == 50_000
    return folder
