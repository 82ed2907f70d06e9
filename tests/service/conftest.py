"""Fixtures of the service tests: apps on the tiny model, a slowed copy of it, test clouds."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from numpy.typing import NDArray

from itnet.pose.runtime import LoadedModel, load_models
from itnet.service.app import create_app
from itnet.service.settings import LimitSettings, Settings

# Small limits so that every limit can be crossed cheaply in a test.
TEST_LIMITS = LimitSettings(
    min_points=32,
    max_points=4096,
    max_budget_ms=5000,
    max_iterations=50,
    max_body_bytes=256 * 1024,
    max_ws_message_bytes=256 * 1024,
    max_concurrent_requests=8,
)


def cloud(n: int = 300, seed: int = 0) -> NDArray[np.float32]:
    """A box-shaped cloud (n, 3), float32-exact so JSON and binary bodies carry the same numbers."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(-1, 1, size=(n, 3)) * [0.3, 0.5, 0.2] + [1.0, -2.0, 3.0]).astype(np.float32)


@pytest.fixture(scope="session")
def make_cloud() -> Callable[..., NDArray[np.float32]]:
    return cloud


@pytest.fixture(scope="module")
def settings(tiny_model_dir: Path) -> Settings:
    return Settings(model_dir=tiny_model_dir, limits=TEST_LIMITS)


@pytest.fixture(scope="module")
def client(settings: Settings) -> Iterator[TestClient]:
    """A client of the app serving the tiny model (module-scoped: loaded once)."""
    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def slow_model(settings: Settings, slow_copy: Callable[..., Any]) -> Any:
    (model,) = load_models(settings.model_dir, warm_up=False).values()
    slow = slow_copy(model, delay_s=0.03)
    slow.warm_up(runs=2)  # as at start-up: the engine then knows a step takes 30 ms
    return slow


@pytest.fixture(scope="module")
def slow_client(settings: Settings, slow_model: LoadedModel) -> Iterator[TestClient]:
    """A client of an app whose model takes 30 ms a step."""
    with TestClient(create_app(settings, models={"tiny": slow_model})) as test_client:
        yield test_client
