"""Fixtures of the ensemble mode's tests: the tiny model and a cloud to run it on."""

import pytest

from itnet.pose.runtime import load_model


@pytest.fixture(scope="module")
def model(tiny_model_dir):
    return load_model(tiny_model_dir / "tiny.onnx", warm_up=False)


@pytest.fixture
def cloud(rng):
    return rng.normal(size=(700, 3)) * [1.0, 0.5, 0.3] + [2.0, -1.0, 4.0]
