"""The height prior: a scene object's top above the floor weighs into its category."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scene_helpers import boxes_shape

import itnet.scene.posing as posing
from itnet.model.classify.size_prior import INCH_M
from itnet.model.heights import measure
from itnet.planes import Plane
from itnet.scene.height_prior import HEIGHTS_M, height_log_likelihood, with_height
from itnet.scene.pipeline import shipped_catalog


def test_a_night_stands_height_favours_the_night_stand_and_a_dressers_the_dresser() -> None:
    night, dresser = height_log_likelihood(["night_stand", "dresser"], 0.62)
    assert night > dresser
    night, dresser = height_log_likelihood(["night_stand", "dresser"], 1.1)
    assert dresser > night
    # a category the table does not know gets no evidence either way
    assert height_log_likelihood(["mug"], 0.1).tolist() == [0.0]


def test_with_height_renormalises_and_can_overturn_a_close_call() -> None:
    names = ["night_stand", "dresser", "chair"]
    tall = with_height(names, [0.55, 0.40, 0.05], 1.15)
    assert tall.sum() == pytest.approx(1.0)
    assert names[int(np.argmax(tall))] == "dresser"
    low = with_height(names, [0.40, 0.55, 0.05], 0.6)
    assert names[int(np.argmax(low))] == "night_stand"
    # a confident classifier is not overruled by an ordinary height
    sure = with_height(names, [0.02, 0.97, 0.01], 0.75)
    assert names[int(np.argmax(sure))] == "dresser"


def test_the_table_is_measured_in_inches_along_modelnets_up(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    for name, inches in (("stool", 20.0), ("wardrobe", 75.0)):
        folder = tmp_path / name / "train"
        folder.mkdir(parents=True)
        for k, scale in enumerate((0.9, 1.0, 1.1)):
            cloud = rng.uniform(0, 1, size=(200, 3)) * [10, 10, 1]
            cloud[:, 2] = np.linspace(0, inches * scale, 200)
            np.save(folder / f"{name}_{k}.npy", cloud)
    table = measure(tmp_path)
    assert table["stool"][0] == pytest.approx(20 * INCH_M, abs=0.01)
    assert table["wardrobe"][0] == pytest.approx(75 * INCH_M, abs=0.01)
    assert 0 < table["stool"][1] < 0.2
    assert set(HEIGHTS_M) >= {"dresser", "night_stand", "chair"}


def test_pose_object_weighs_the_height_into_the_category(monkeypatch) -> None:
    """The classifier's close call between a night stand and a dresser goes by the object's top,
    and the pose comes from the chosen category's model."""
    fake = SimpleNamespace(
        candidates=[
            SimpleNamespace(category="night_stand", probability=0.55),
            SimpleNamespace(category="dresser", probability=0.45),
        ],
        threshold=0.3,
    )
    monkeypatch.setattr(posing, "classify", lambda *args, **kwargs: fake)
    box = boxes_shape([((0, 0, 0), (0.5, 1.1, 0.4))])
    points = 0.45 * box.points[:800] + np.array([0.0, 0.0, 3.0])  # night-stand sized
    up, viewpoint = np.array([0.0, -1.0, 0.0]), np.zeros(3)
    catalog = shipped_catalog()

    def floor_under(top_m: float) -> Plane:  # up is -y: the top is the least y
        return Plane(up, float(points[:, 1].min()) + top_m)

    plain = posing.pose_object(catalog, points, up, viewpoint, 500.0)
    tall = posing.pose_object(catalog, points, up, viewpoint, 500.0, floor=floor_under(1.1))
    low = posing.pose_object(catalog, points, up, viewpoint, 500.0, floor=floor_under(0.6))
    assert plain.category == "night_stand" and low.category == "night_stand"
    assert tall.category == "dresser" and tall.pose is not None
    assert tall.result is not None and tall.result["model"] == "dresser"
    # the dresser's card recommends one run; an object of a scene gets at least SCENE_LEAST_RUNS
    assert catalog.models["dresser"].card.recommended_ensemble < posing.SCENE_LEAST_RUNS
    assert tall.result["ensemble"] == posing.SCENE_LEAST_RUNS
    assert [c["category"] for c in tall.candidates[:2]] == ["dresser", "night_stand"]
    assert sum(c["probability"] for c in tall.candidates) == pytest.approx(1.0, abs=1e-5)
