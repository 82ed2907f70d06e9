"""The scene tab in a real browser (headless Chromium) against a live ``itnet serve``: a dropped
depth image gives the objects the API gives, drawn over the scene."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from benchmarks.harness import Server
from itnet.model.scenes import Scene
from itnet.scene.depth_io import depth_to_png
from itnet.scene.pipeline import DEFAULT_BUDGET_MS

pytestmark = [pytest.mark.e2e, pytest.mark.slow]
DONE = "['done', 'failed'].includes(document.body.dataset.run)"


def test_a_dropped_depth_image_shows_the_apis_objects(
    live_server: Server, browser_page: Any, chair_scene: Scene, tmp_path: Path
) -> None:
    page = browser_page
    png = tmp_path / "chair.png"
    png.write_bytes(depth_to_png(np.round(chair_scene.depth * 1000).astype(np.uint16)))
    i = chair_scene.intrinsics
    camera = f"{i.fx},{i.fy},{i.cx},{i.cy}"
    errors: list[str] = []
    page.on("pageerror", lambda err: errors.append(str(err)))
    page.goto(f"{live_server.url}/?tab=scene&budget_ms=2000")
    page.wait_for_function("document.body.dataset.ready === 'true'")
    page.set_input_files("#file-scene", str(png))
    page.fill("#intrinsics", camera)
    page.click("#run")
    page.wait_for_function(DONE, timeout=30_000)
    assert page.evaluate("document.body.dataset.run") == "done", page.text_content("#status")
    shown = json.loads(page.text_content("#result"))
    query = dict(zip(["fx", "fy", "cx", "cy"], camera.split(","), strict=True))
    api = httpx.post(f"{live_server.url}/v1/scene", params={**query, "budget_ms": 2000},
                     content=png.read_bytes(), headers={"content-type": "image/png"},
                     timeout=30).json()  # fmt: skip
    assert [o["category"] for o in shown["objects"]] == [o["category"] for o in api["objects"]]
    assert len(shown["objects"]) == 1
    assert page.locator("#scene-objects li").count() == 1
    (obj,) = api["objects"]
    listed = page.text_content("#scene-objects li")
    assert listed.startswith(obj["category"]) and ("(unsure)" in listed) == obj["unsure"]
    assert not errors
    # the drawn scene: its points, one box, and the object's axes where it has a pose
    drawn = page.evaluate("document.querySelectorAll('canvas#view3d').length")
    assert drawn == 1


def test_the_example_scene_runs_as_the_page_opens_it(
    live_server: Server, browser_page: Any
) -> None:
    """The scene tab opens on the shipped example scene, its intrinsics typed and the scene's
    budget (the API's default) in the field: Run finds its three objects, each named right or,
    where a busy machine's budget ran out first, unnamed for the budget; a dropped file takes its
    place, choosing the example again brings it back, and a budget that holds them all names all
    three."""
    examples = Path(__file__).resolve().parents[2] / "itnet" / "examples"
    truth = json.loads((examples / "scene_truth.json").read_text())
    camera = json.loads((examples / "scene_camera.json").read_text())
    page = browser_page
    page.goto(f"{live_server.url}/?tab=scene")
    page.wait_for_function("document.body.dataset.ready === 'true'")
    assert page.input_value("#example-scene") == "scene"
    assert float(page.input_value("#budget")) == DEFAULT_BUDGET_MS
    typed = [float(v) for v in page.input_value("#intrinsics").split(",")]
    assert typed == [camera[k] for k in ("fx", "fy", "cx", "cy")]
    page.click("#run")
    page.wait_for_function(DONE, timeout=30_000)
    assert page.evaluate("document.body.dataset.run") == "done", page.text_content("#status")
    shown = json.loads(page.text_content("#result"))
    expected = sorted(o["category"] for o in truth["objects"])
    assert len(shown["objects"]) == 3 and page.locator("#scene-objects li").count() == 3
    named = [o["category"] for o in shown["objects"] if o["category"] is not None]
    assert all(o["unknown"] == "budget" for o in shown["objects"] if o["category"] is None)
    assert set(named) <= set(expected) and len(set(named)) == len(named)
    assert shown["budget_ms"] == DEFAULT_BUDGET_MS
    # the pose tab keeps its own budget
    page.click("button.tab[data-tab='pose']")
    assert page.input_value("#budget") == "50"
    page.click("button.tab[data-tab='scene']")
    page.set_input_files("#file-scene", str(examples / "scene_camera.json"))
    assert page.evaluate("document.querySelector('#file-scene').files.length") == 1
    page.select_option("#example-scene", "scene")
    assert page.evaluate("document.querySelector('#file-scene').files.length") == 0
    assert "tab=scene" in page.url and "scene=scene" in page.url and "budget_ms" not in page.url
    page.fill("#budget", "5000")
    page.evaluate("document.body.dataset.run = ''")
    page.click("#run")
    page.wait_for_function(DONE, timeout=30_000)
    shown = json.loads(page.text_content("#result"))
    assert sorted(o["category"] for o in shown["objects"]) == expected
    assert shown["budget_ms"] == 5000


def test_the_up_field_finds_a_steep_cameras_floor(
    live_server: Server, browser_page: Any, tmp_path: Path
) -> None:
    """A camera pitched 60 degrees down: without up the page finds no object; with the IMU's up
    typed in its field it finds the chair; an up that is no direction is refused, said in the
    status line."""
    from scene_helpers import chair_shape, make_test_scene

    pitch = np.radians(60.0)
    up = f"0,{-np.cos(pitch):.6f},{-np.sin(pitch):.6f}"
    scene = make_test_scene([(chair_shape(), 0.5, 0.0, 1.2, 150.0)], pitch_deg=60.0)
    png = tmp_path / "steep.png"
    png.write_bytes(depth_to_png(np.round(scene.depth * 1000).astype(np.uint16)))
    i = scene.intrinsics
    page = browser_page
    page.goto(f"{live_server.url}/?tab=scene&budget_ms=2000")
    page.wait_for_function("document.body.dataset.ready === 'true'")
    page.set_input_files("#file-scene", str(png))
    page.fill("#intrinsics", f"{i.fx},{i.fy},{i.cx},{i.cy}")
    found = []
    for typed in ("", up, "0,0,0"):
        page.fill("#scene-up", typed)
        page.evaluate("document.body.dataset.run = ''")
        page.click("#run")
        page.wait_for_function(DONE, timeout=30_000)
        if typed == "0,0,0":
            assert page.evaluate("document.body.dataset.run") == "failed"
            assert "up" in page.text_content("#status")
        else:
            assert page.evaluate("document.body.dataset.run") == "done"
            found.append(page.locator("#scene-objects li").count())
    assert found == [0, 1]
