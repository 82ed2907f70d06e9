"""The scene path's warm-up: its made-up view is a scene with one object on a floor, and the CLI
and the service run it before their first scene (the service warms its alignment up too)."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from itnet.scene import SceneFinishing, find_objects
from itnet.scene.warm_up import CAMERA, CAMERA_HEIGHT_M, made_up_view
from itnet.service.app import create_app
from itnet.service.settings import Settings


def test_the_made_up_view_is_a_floor_with_one_object_on_it() -> None:
    depth = made_up_view()
    assert depth.dtype == np.uint16 and (depth[0] == 0).all()  # the upper rows see nothing
    found = find_objects(
        depth / 1000.0, CAMERA, budget_ms=2000, finishing=SceneFinishing(unknown=False)
    )  # as warm_up finds it
    assert found.floor is not None
    assert abs(found.floor.offset - CAMERA_HEIGHT_M) < 0.02  # the camera 1.4 m over it
    (obj,) = found.objects
    assert obj.pose is not None and 0.7 < obj.box.size[1] < 0.9  # the 0.8 m box, posed
    (plain,) = find_objects(depth / 1000.0, CAMERA, budget_ms=2000).objects
    assert 0.7 < plain.box.size[1] < 0.9  # a plain box: named or unknown, never dropped


@pytest.mark.parametrize("step", ["warm_up_scenes", "warm_up_alignment"])
@pytest.mark.parametrize("warm", [True, False])
def test_the_service_warms_the_scene_path_and_the_alignment_at_start_up(
    monkeypatch, warm: bool, step: str
) -> None:
    import itnet.service.app as app_module

    calls = []
    monkeypatch.setattr(app_module, step, lambda *catalog: calls.append(catalog))
    with TestClient(create_app(Settings(warm_up=warm))) as client:
        assert client.get("/readyz").status_code == 200
    assert len(calls) == (1 if warm else 0)
    if warm and step == "warm_up_scenes":
        assert calls[0][0].classifier is not None


def test_a_failed_warm_up_leaves_the_service_serving(monkeypatch) -> None:
    import itnet.service.app as app_module

    def fails(catalog: object) -> None:
        raise RuntimeError("no")

    monkeypatch.setattr(app_module, "warm_up_scenes", fails)
    with TestClient(create_app(Settings())) as client:
        assert client.get("/readyz").status_code == 200


def test_the_cli_warms_up_before_its_first_file(monkeypatch, tmp_path) -> None:
    from typer.testing import CliRunner

    import itnet.scene.warm_up as warm_module
    from itnet.cli import app

    calls = []
    monkeypatch.setattr(warm_module, "warm_up", lambda catalog: calls.append(catalog))
    cloud = tmp_path / "empty.npy"
    np.save(cloud, np.zeros((0, 3)))
    CliRunner().invoke(app, ["scene", str(cloud)])
    assert len(calls) == 1
