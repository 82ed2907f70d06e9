"""The shipped models on a chair of boxes before a wall: the CLI, HTTP and Python see the same
one object, with its category, a pose where its category has a model, and its pixels."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from itnet.cli import app
from itnet.model.scenes import Scene
from itnet.scene import find_objects, pipeline
from itnet.scene.depth_io import depth_to_png
from itnet.service.app import create_app

runner = CliRunner()


def depth_mm(scene: Scene) -> np.ndarray:
    return np.round(scene.depth * 1000).astype(np.uint16)


def camera_arg(scene: Scene) -> str:
    i = scene.intrinsics
    return f"{i.fx},{i.fy},{i.cx},{i.cy}"


def check_the_chair(objects: list[dict], scene: Scene) -> None:
    assert len(objects) == 1
    obj = objects[0]
    assert obj["category"] and 0 < obj["category_probability"] <= 1
    assert (obj["T_canonical_from_input"] is None) == (obj.get("no_pose") is not None)
    if obj["T_canonical_from_input"] is not None:
        pose = np.asarray(obj["T_canonical_from_input"])
        assert pose.shape == (4, 4) and np.allclose(
            pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-5
        )
    pixels = np.asarray(obj["indices"])
    labels = scene.labels.ravel()
    assert (labels[pixels] == 1).mean() > 0.98 and len(pixels) > 0.8 * (labels == 1).sum()
    centre = np.asarray(obj["box"]["center"])
    assert 2.0 < centre[2] < 4.0  # about 3 m ahead


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory, chair_scene: Scene, empty_scene: Scene) -> Path:
    folder = tmp_path_factory.mktemp("scenes")
    (folder / "chair.png").write_bytes(depth_to_png(depth_mm(chair_scene)))
    (folder / "empty.png").write_bytes(depth_to_png(depth_mm(empty_scene)))
    np.save(folder / "chair_m.npy", chair_scene.depth.astype(np.float32))
    (folder / "nothing.png").write_bytes(depth_to_png(np.zeros((20, 30), np.uint16)))
    return folder


def test_cli_json_lines_and_bad_files(files: Path, chair_scene: Scene) -> None:
    args = ["scene", str(files / "chair.png"), str(files / "nothing.png"),
            str(files / "chair_m.npy"), str(files / "empty.png"),
            "--intrinsics", camera_arg(chair_scene), "--json", "--budget-ms", "300"]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 2  # nothing.png has no valid depth; the others are answered
    assert "nothing.png: the depth image has no valid depth" in result.stderr
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert [Path(line["file"]).name for line in lines] == ["chair.png", "chair_m.npy", "empty.png"]
    check_the_chair(lines[0]["objects"], chair_scene)
    check_the_chair(lines[1]["objects"], chair_scene)
    assert lines[2]["objects"] == []  # an empty floor: no objects, not an error


def test_cli_without_intrinsics_is_a_one_line_error(files: Path) -> None:
    result = runner.invoke(app, ["scene", str(files / "chair.png")])
    assert result.exit_code == 2
    assert result.stderr.strip().count("\n") == 0 and "intrinsics" in result.stderr


@pytest.fixture(scope="module")
def client():
    with TestClient(create_app()) as client:
        yield client


def test_http_png_json_and_the_python_api_agree(client: TestClient, files: Path,
                                                 chair_scene: Scene) -> None:  # fmt: skip
    i = chair_scene.intrinsics
    query = f"fx={i.fx}&fy={i.fy}&cx={i.cx}&cy={i.cy}&budget_ms=300"
    png = (files / "chair.png").read_bytes()
    reply = client.post(f"/v1/scene?{query}", content=png, headers={"content-type": "image/png"})
    assert reply.status_code == 200, reply.text
    check_the_chair(reply.json()["objects"], chair_scene)
    assert reply.json()["up"][1] < -0.9  # the floor's normal: about -y in a level camera
    assert reply.json()["objects"][0]["base_out_of_view"] is False  # seen down to the floor
    result = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=300)
    assert [o.category for o in result.objects] == [reply.json()["objects"][0]["category"]]


def test_the_first_call_of_a_process_loads_the_models_before_its_budget_starts(
    chair_scene: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(pipeline, "_SHIPPED", None)  # as in a fresh process: none loaded yet
    result = find_objects(chair_scene.depth, chair_scene.intrinsics, budget_ms=300)
    assert [o.category for o in result.objects] == ["chair"]
    assert result.objects[0].pose is not None


@pytest.mark.parametrize(
    ("body", "kind", "query", "status", "said"),
    [
        (b"\x89PNG\r\n\x1a\n" + b"x" * 40, "image/png", "fx=1&fy=1&cx=1&cy=1", 422, ""),
        (depth_to_png(np.ones((4, 4), np.uint16)), "image/png", "", 422, "intrinsics"),
        (
            depth_to_png(np.zeros((8, 8), np.uint16)),
            "image/png",
            "fx=5&fy=5&cx=4&cy=4",
            422,
            "no valid depth",
        ),
        (
            depth_to_png(np.ones((1100, 1300), np.uint16)),
            "image/png",
            "fx=5&fy=5&cx=4&cy=4",
            413,
            "over the limit",
        ),
        (b"abcd", "application/octet-stream", "", 400, "multiple of 12"),
        (b"hello", "text/plain", "", 415, "image/png"),
        (b'{"points": [[1, 2]]}', "application/json", "", 422, "(N, 3)"),
        (
            np.zeros((100, 3), np.float32).tobytes(),
            "application/octet-stream",
            "budget_ms=0",
            422,
            "budget_ms",
        ),
    ],
)
def test_http_bad_scenes_get_their_4xx_and_the_service_keeps_serving(
    client: TestClient, body: bytes, kind: str, query: str, status: int, said: str
) -> None:
    reply = client.post(f"/v1/scene?{query}", content=body, headers={"content-type": kind})
    assert reply.status_code == status, reply.text
    assert said in reply.json()["detail"]
    cloud = np.random.default_rng(0).normal(size=(200, 3)) + np.array([0.0, 0.0, 3.0])
    ok = client.post("/v1/scene", content=cloud.astype("<f4").tobytes(),
                     headers={"content-type": "application/octet-stream"})  # fmt: skip
    assert ok.status_code == 200 and ok.json()["objects"] == []  # no floor: no objects


def test_the_finishing_steps_switch_off_on_the_cli_and_http(
    client: TestClient, files: Path, chair_scene: Scene
) -> None:
    """``--no-floor-centre`` / ``floor_centre=false`` and the others reach find_objects: an
    object without them has the network's own centre and no finishing fields."""
    args = ["scene", str(files / "chair.png"), "--intrinsics", camera_arg(chair_scene), "--json",
            "--budget-ms", "300"]  # fmt: skip
    off = ["--no-floor-centre", "--no-along-floor", "--no-recheck", "--no-scene-classifier"]
    on, bare = (json.loads(runner.invoke(app, args + extra).output) for extra in ([], off))
    (finished,), (plain,) = on["objects"], bare["objects"]
    assert finished["T_canonical_from_input"] is not None  # every category has a pose model
    assert finished["centre_floor"] is True and "centre_floor" not in plain
    assert "category_recheck" not in plain
    assert finished["named_by"] == "scene_classifier" and plain["named_by"] == "classifier"
    i = chair_scene.intrinsics
    query = (f"fx={i.fx}&fy={i.fy}&cx={i.cx}&cy={i.cy}&budget_ms=300"
             "&floor_centre=false&along_floor=false&recheck=false&scene_classifier=false")  # fmt: skip
    png = (files / "chair.png").read_bytes()
    reply = client.post(f"/v1/scene?{query}", content=png, headers={"content-type": "image/png"})
    assert reply.status_code == 200, reply.text
    (obj,) = reply.json()["objects"]
    assert "centre_floor" not in obj and "category_recheck" not in obj
    assert obj["named_by"] == "classifier"


def test_the_touching_cut_switches_off_on_the_cli_http_and_clients(
    client: TestClient, files: Path, chair_scene: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With a cut judge that finds two objects in every cluster, the chair is cut; with
    ``--no-split-touching`` / ``split_touching=false`` it stays one object."""
    from scene_helpers import sure_judge

    from itnet.clients import ItnetClient
    from itnet.scene import segment as segment_module

    monkeypatch.setattr(segment_module, "load_cut_judge", lambda: sure_judge("two"))
    args = ["scene", str(files / "chair.png"), "--intrinsics", camera_arg(chair_scene), "--json",
            "--budget-ms", "300"]  # fmt: skip
    cut, whole = (json.loads(runner.invoke(app, args + extra).output)["objects"]
                  for extra in ([], ["--no-split-touching"]))  # fmt: skip
    assert len(cut) >= 2 and len(whole) == 1
    i = chair_scene.intrinsics
    query = f"fx={i.fx}&fy={i.fy}&cx={i.cx}&cy={i.cy}&budget_ms=300&split_touching=false"
    png = (files / "chair.png").read_bytes()
    reply = client.post(f"/v1/scene?{query}", content=png, headers={"content-type": "image/png"})
    assert reply.status_code == 200, reply.text
    assert len(reply.json()["objects"]) == 1
    sync = ItnetClient("http://testserver")
    sync._http = client
    camera = (i.fx, i.fy, i.cx, i.cy)
    assert (
        len(sync.scene(png, intrinsics=camera, budget_ms=300, split_touching=False)["objects"]) == 1
    )
    assert len(sync.scene(png, intrinsics=camera, budget_ms=300)["objects"]) >= 2


def test_unknown_objects_switch_off_on_the_cli_http_and_clients(
    client: TestClient, files: Path, chair_scene: Scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where no probability is high enough, the chair is unknown: category null, why, no pose,
    its box and points; with ``--no-unknown`` / ``unknown=false`` it is named and posed."""
    from itnet.clients import ItnetClient
    from itnet.scene import unknown as unknown_module

    monkeypatch.setattr(unknown_module, "UNKNOWN_BELOW", 1.01)
    args = ["scene", str(files / "chair.png"), "--intrinsics", camera_arg(chair_scene), "--json",
            "--budget-ms", "300"]  # fmt: skip
    (unsure,), (named,) = (json.loads(runner.invoke(app, args + extra).output)["objects"]
                           for extra in ([], ["--no-unknown"]))  # fmt: skip
    assert unsure["category"] is None and unsure["unknown"] == "unsure"
    assert unsure["T_canonical_from_input"] is None and unsure["no_pose"] == "unknown"
    assert unsure["points"] == named["points"] > 0 and unsure["box"]["size"]
    assert named["category"] is not None and named["T_canonical_from_input"] is not None
    text = runner.invoke(app, args[:4]).output
    assert "unknown: unsure" in text
    i = chair_scene.intrinsics
    png = (files / "chair.png").read_bytes()
    query = f"fx={i.fx}&fy={i.fy}&cx={i.cx}&cy={i.cy}&budget_ms=300&unknown=false"
    reply = client.post(f"/v1/scene?{query}", content=png, headers={"content-type": "image/png"})
    assert reply.status_code == 200, reply.text
    assert reply.json()["objects"][0]["category"] is not None
    sync = ItnetClient("http://testserver")
    sync._http = client
    camera = (i.fx, i.fy, i.cx, i.cy)
    assert sync.scene(png, intrinsics=camera, budget_ms=300)["objects"][0]["category"] is None
    shown = sync.scene(png, intrinsics=camera, budget_ms=300, unknown=False)["objects"][0]
    assert shown["category"] is not None


def test_the_python_clients_send_a_scene_as_png_npy_or_cloud(
    client: TestClient, files: Path, chair_scene: Scene
) -> None:
    """``ItnetClient.scene`` and ``AsyncItnetClient.scene``: a PNG file, PNG bytes and a float
    depth image find the same one object, and so does the scene as a cloud (no intrinsics)."""
    import asyncio

    import httpx

    from itnet.clients import AsyncItnetClient, ItnetClient
    from itnet.scene.inputs import from_depth

    i = chair_scene.intrinsics
    camera = (i.fx, i.fy, i.cx, i.cy)
    sync = ItnetClient("http://testserver")
    sync._http = client  # the app in-process: TestClient is an httpx.Client
    png = files / "chair.png"
    replies = [
        sync.scene(png, intrinsics=camera, budget_ms=300),
        sync.scene(png.read_bytes(), intrinsics=camera, budget_ms=300, indices=False),
        sync.scene(chair_scene.depth.astype(np.float32), intrinsics=camera, budget_ms=300),
        sync.scene(from_depth(chair_scene.depth, chair_scene.intrinsics).points, budget_ms=300),
    ]
    for reply in replies:
        assert len(reply["objects"]) == 1 and reply["up"][1] < -0.9
    check_the_chair(replies[0]["objects"], chair_scene)
    assert "indices" not in replies[1]["objects"][0]
    assert replies[3]["image_shape"] is None  # a cloud has no image

    async def from_async() -> dict:
        remote = AsyncItnetClient("http://testserver")
        remote._http = httpx.AsyncClient(transport=httpx.ASGITransport(app=client.app),
                                         base_url="http://testserver")  # fmt: skip
        async with remote:
            return await remote.scene(png, intrinsics=camera, budget_ms=300, recheck=False,
                                      scene_classifier=False)  # fmt: skip

    (obj,) = asyncio.run(from_async())["objects"]
    assert obj["category"] and "category_recheck" not in obj and obj["named_by"] == "classifier"
    assert replies[0]["objects"][0]["named_by"] == "scene_classifier"
    with pytest.raises(ValueError, match=".png or .npy"):
        sync.scene(files / "chair.ply")


def test_a_camera_pitched_60_degrees_finds_its_floor_when_told_up(
    client: TestClient, tmp_path: Path
) -> None:
    """A camera pitched 60 degrees down looks past the floor search's 45 degrees about -y: no
    floor, no object; told which way is up (``expected_up``, ``--up``, ``up=``, the clients'
    ``up``), it finds the chair below it. An up that is no direction is refused."""
    from scene_helpers import chair_shape, make_test_scene

    from itnet.clients import ItnetClient

    pitch = np.radians(60.0)
    up = (0.0, -float(np.cos(pitch)), -float(np.sin(pitch)))
    scene = make_test_scene([(chair_shape(), 0.5, 0.0, 1.2, 150.0)], pitch_deg=60.0)
    assert find_objects(scene.depth, scene.intrinsics, budget_ms=300).objects == []
    told = find_objects(scene.depth, scene.intrinsics, budget_ms=300, expected_up=up)
    assert len(told.objects) == 1 and told.up is not None and told.up @ np.array(up) > 0.999
    with pytest.raises(ValueError, match="expected_up"):
        find_objects(scene.depth, scene.intrinsics, expected_up=(0.0, 0.0, 0.0))

    png = depth_to_png(depth_mm(scene))
    (tmp_path / "steep.png").write_bytes(png)
    args = ["scene", str(tmp_path / "steep.png"), "--intrinsics", camera_arg(scene), "--json",
            "--budget-ms", "300"]  # fmt: skip
    text = ",".join(map(str, up))
    assert json.loads(runner.invoke(app, args).output)["objects"] == []
    assert len(json.loads(runner.invoke(app, [*args, "--up", text]).output)["objects"]) == 1
    assert runner.invoke(app, [*args, "--up", "0,0,0"]).exit_code == 2

    i = scene.intrinsics
    query = f"fx={i.fx}&fy={i.fy}&cx={i.cx}&cy={i.cy}&budget_ms=300"
    headers = {"content-type": "image/png"}
    reply = client.post(f"/v1/scene?{query}&up={text}", content=png, headers=headers)
    assert reply.status_code == 200, reply.text
    assert len(reply.json()["objects"]) == 1
    for bad in ("1,2", "0,0,0", "nan,1,0"):
        refused = client.post(f"/v1/scene?{query}&up={bad}", content=png, headers=headers)
        assert refused.status_code == 422 and refused.json()["kind"] == "invalid_request"
    sync = ItnetClient("http://testserver")
    sync._http = client
    camera = (i.fx, i.fy, i.cx, i.cy)
    assert len(sync.scene(png, intrinsics=camera, budget_ms=300, up=up)["objects"]) == 1
