"""Fixtures of the classification tests: tiny classifiers exported to ONNX whose answer is fixed
by their last layer (zero weights, chosen biases), beside a tiny pose model."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from cls_helpers import SHAPES, export_fixed


@pytest.fixture(scope="session")
def pose_dir(tmp_path_factory: pytest.TempPathFactory, export_model: Callable[..., Path]) -> Path:
    """A folder with one tiny pose model: name 'chair', category 'chair'."""
    from itnet.model_card import ModelCard

    folder = tmp_path_factory.mktemp("pose")
    card = ModelCard(name="chair", category="chair", points=128, recommended_iterations=4)
    export_model(card, folder / "chair.onnx")
    return folder


def _with_classifier(
    pose_dir: Path, tmp: pytest.TempPathFactory, name: str, logits: list[float], threshold: float
) -> Path:
    folder = tmp.mktemp(name)
    shutil.copy(pose_dir / "chair.onnx", folder / "chair.onnx")
    export_fixed(folder, logits, threshold)
    return folder


@pytest.fixture(scope="session")
def chair_dir(pose_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The chair pose model and a classifier that always says 'chair' (p = 0.99)."""
    return _with_classifier(pose_dir, tmp_path_factory, "says_chair", [6.0, 0.0, 0.0], 0.5)


@pytest.fixture(scope="session")
def table_dir(pose_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The chair pose model and a classifier that always says 'table' (no table model)."""
    return _with_classifier(pose_dir, tmp_path_factory, "says_table", [0.0, 6.0, 1.0], 0.5)


@pytest.fixture(scope="session")
def unsure_dir(pose_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A classifier that leans to 'chair' (p = 0.45) below its threshold 0.6."""
    return _with_classifier(pose_dir, tmp_path_factory, "unsure", [0.5, 0.0, 0.0], 0.6)


@pytest.fixture
def box_cloud() -> np.ndarray:
    rng = np.random.default_rng(3)
    return (rng.uniform(-1, 1, size=(300, 3)) * [0.3, 0.5, 0.2] + [1.0, -2.0, 3.0]).astype(
        np.float32
    )


@pytest.fixture(scope="module")
def three_classes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three synthetic classes (plate, rod, ball), 8 train and 2 test shapes each."""
    rng = np.random.default_rng(0)
    root = tmp_path_factory.mktemp("classes")
    for name, make in SHAPES.items():
        for split, count in (("train", 8), ("test", 2)):
            (root / name / split).mkdir(parents=True)
            for i in range(count):
                np.save(
                    root / name / split / f"{name}_{i}.npy",
                    make(rng, 400) * rng.uniform(0.8, 1.2, 3),
                )
    return root
