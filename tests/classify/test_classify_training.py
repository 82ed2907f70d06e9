"""A tiny classification run on synthetic classes (a flat plate, a long rod, a ball) in the
ModelNet layout: the loss falls, the result has test metrics, and a rerun resumes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from itnet.model.classify_train import ClassifyConfig, train

SHAPES = {
    "plate": lambda r, n: r.uniform(-1, 1, (n, 3)) * [1.0, 0.05, 0.7],
    "rod": lambda r, n: r.uniform(-1, 1, (n, 3)) * [0.08, 1.0, 0.08],
    "ball": lambda r, n: (lambda v: v / np.linalg.norm(v, axis=1, keepdims=True))(
        r.normal(size=(n, 3))
    ),
}


@pytest.fixture(scope="module")
def three_classes(tmp_path_factory: pytest.TempPathFactory) -> Path:
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


def test_tiny_training_lowers_the_loss_and_resumes(three_classes: Path, tmp_path: Path) -> None:
    config = ClassifyConfig(
        data=three_classes, variant="itnet-1", out=tmp_path / "run", cache=tmp_path / "cache",
        steps=60, batch=16, points=64, lr=3e-3, decay_every=1000, eval_every=30, log_every=10,
        val_views=2, test_views=2, widths=((16, 32, 64), (32, 16)), bf16=False,
    )  # fmt: skip
    result = train(config)
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    losses = [entry["loss"] for entry in log if "loss" in entry]
    assert len(losses) == 6 and np.mean(losses[-2:]) < 0.8 * np.mean(losses[:2]), losses
    assert result["classes"] == ["ball", "plate", "rod"]
    assert result["test"]["scans"] == 3 * 2 * 2 and 0 <= result["test"]["accuracy"] <= 1
    assert set(result["test"]["per_class"]) == {"ball", "plate", "rod"}
    assert np.array(result["test"]["confusion"]).sum() == 12
    # a longer rerun resumes from the last checkpoint instead of starting over
    (tmp_path / "run" / "result.json").unlink()
    train(config.model_copy(update={"steps": 70}))
    starts = [
        e
        for e in map(json.loads, (tmp_path / "run" / "log.jsonl").read_text().splitlines())
        if e.get("event") == "start"
    ]
    assert [s["step"] for s in starts] == [0, 60]
