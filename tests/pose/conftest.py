"""Fixtures of the pose pipeline's tests (the tiny model itself: ``tests/conftest.py: model``)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def cloud() -> np.ndarray:
    """An elongated blob of 400 points (N, 3), seeded: a cloud every plan can run on."""
    return np.random.default_rng(5).normal(size=(400, 3)) * [0.3, 0.2, 0.1]
