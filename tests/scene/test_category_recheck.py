"""A scene object's category rechecked by the verifiers: the logit, and find_objects keeping the
first category, changing to the second, or saying the budget held no second pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from itnet.cloud_io import read_cloud
from itnet.geometry import axis_angle_to_matrix
from itnet.model.scenes import Scene
from itnet.pose.request import PoseRequest
from itnet.scene import SceneFinishing, category_recheck, find_objects
from itnet.scene.category_recheck import pose_logit
from itnet.scene.pipeline import shipped_catalog

CHAIR = Path(__file__).resolve().parents[2] / "itnet" / "examples" / "chair_a.ply"


def test_the_verifier_finds_a_served_pose_likelier_than_a_turned_one() -> None:
    catalog = shipped_catalog()
    chair = catalog.models["chair"]
    cloud = read_cloud(CHAIR)
    reply = catalog.pose(cloud, PoseRequest(model="chair", budget_ms=1000))
    pose = np.asarray(reply["T_canonical_from_input"])
    turned = pose.copy()
    turned[:3, :3] = axis_angle_to_matrix([0.0, 1.0, 0.0], np.pi / 2) @ pose[:3, :3]
    right, wrong = pose_logit(chair, cloud, pose), pose_logit(chair, cloud, turned)
    assert right is not None and wrong is not None and right > wrong + 3
    assert pose_logit(chair, cloud, pose) == right  # a fixed draw of the points
    bare = type(chair)(chair.card, chair.path, chair.session)  # no verifier attached
    assert pose_logit(bare, cloud, pose) is None


@pytest.mark.parametrize(
    ("below", "margin", "budget_ms", "outcome"),
    [
        (np.inf, -np.inf, 1000.0, "changed"),  # always doubted, the second always likelier
        (np.inf, np.inf, 1000.0, "kept"),  # always doubted, the second never likelier
        (-np.inf, 0.0, 1000.0, None),  # never doubted
    ],
)
def test_find_objects_keeps_or_changes_a_doubted_category(
    monkeypatch: pytest.MonkeyPatch, chair_scene: Scene, below: float, margin: float,
    budget_ms: float, outcome: str | None,
) -> None:  # fmt: skip
    first = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=budget_ms,
                         finishing=SceneFinishing(recheck=False)).objects[0]  # fmt: skip
    monkeypatch.setattr(category_recheck, "RECHECK_BELOW", below)
    monkeypatch.setattr(category_recheck, "RECHECK_MARGIN", margin)
    (obj,) = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=budget_ms).objects
    assert obj.run is not None and obj.run.get("category_recheck") == outcome
    second = first.candidates[1]["category"]
    assert obj.category == (second if outcome == "changed" else first.category)
    assert obj.unsure == (True if outcome == "changed" else first.unsure)
    assert obj.run["model"] == obj.category and obj.run["centre_floor"] is True  # finished alike
    assert obj.candidates == first.candidates


def test_a_doubted_object_without_time_left_says_so(
    monkeypatch: pytest.MonkeyPatch, chair_scene: Scene
) -> None:
    monkeypatch.setattr(category_recheck, "RECHECK_BELOW", np.inf)
    monkeypatch.setattr(category_recheck, "MIN_RECHECK_MS", 1e6)
    (obj,) = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=1000).objects
    assert obj.run is not None and obj.run["category_recheck"] == "budget"


def test_an_object_whose_base_is_below_the_view_keeps_its_category(
    monkeypatch: pytest.MonkeyPatch, level_chair_scene: Scene
) -> None:
    """The verifiers learned whole objects: a chair seen from its seat up is not rechecked, even
    where every pose is doubted and the second category always likelier; with the rule off
    (``view_edge_deg`` negative: no object reaches the edge) it is."""
    monkeypatch.setattr(category_recheck, "RECHECK_BELOW", np.inf)
    monkeypatch.setattr(category_recheck, "RECHECK_MARGIN", -np.inf)
    scene = level_chair_scene
    named = SceneFinishing(unknown=False)  # the box-built chair is named with little confidence
    (kept,) = find_objects(scene.depth, scene.intrinsics, budget_ms=1000, finishing=named).objects
    assert kept.run is not None and kept.run["category_recheck"] == "base_out_of_view"
    assert kept.category == kept.candidates[0]["category"]
    off = SceneFinishing(view_edge_deg=-90.0, unknown=False)
    (changed,) = find_objects(scene.depth, scene.intrinsics, budget_ms=1000, finishing=off).objects
    assert changed.run is not None and changed.run["category_recheck"] == "changed"
    assert changed.category == kept.candidates[1]["category"]


def test_an_object_whose_base_is_below_the_view_is_posed_by_its_base_hidden_model(
    level_chair_scene: Scene, chair_scene: Scene
) -> None:
    """Where the models have a network for views whose base is below the view (named
    ``<category>_base_hidden``), a chair seen from its seat up is posed by it, a chair seen
    whole by the chair's own, and with ``base_hidden_models`` off both by the chair's own."""
    from dataclasses import replace

    from itnet.pose.catalog import Catalog
    from itnet.scene.posing import BASE_HIDDEN_SUFFIX

    shipped = shipped_catalog()
    name = "chair" + BASE_HIDDEN_SUFFIX
    chair = shipped.models["chair"]
    hidden = replace(chair, card=chair.card.model_copy(update={"name": name}))
    catalog = Catalog({**shipped.models, name: hidden}, shipped.classifier)
    off = SceneFinishing(base_hidden_models=False)
    for scene, finishing, model in (
        (level_chair_scene, SceneFinishing(), name),
        (chair_scene, SceneFinishing(), "chair"),
        (level_chair_scene, off, "chair"),
    ):
        (obj,) = find_objects(scene.depth, scene.intrinsics, budget_ms=1000, catalog=catalog,
                              finishing=finishing, categories=frozenset({"chair"})).objects  # fmt: skip
        assert obj.category == "chair" and obj.run is not None and obj.run["model"] == model
        assert obj.base_out_of_view is (scene is level_chair_scene)  # said whatever the model
        assert obj.as_dict()["base_out_of_view"] is obj.base_out_of_view
