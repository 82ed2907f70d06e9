"""The page's routes in-process (TestClient, tiny model): the page and its files, the examples,
reading a dropped file with itnet.cloud_io, and POST /v1/align."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from itnet.cloud_io import read_cloud, write_ply
from itnet.service.app import create_app
from itnet.service.settings import LimitSettings, Settings

EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"
LIMITS = LimitSettings(max_points=2000, max_body_bytes=160 * 1024, max_budget_ms=5000)


@pytest.fixture(scope="module")
def client(tiny_model_dir: Path) -> Iterator[TestClient]:
    with TestClient(create_app(Settings(model_dir=tiny_model_dir, limits=LIMITS))) as test:
        yield test


def test_the_page_and_its_files_are_served(client):
    page = client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'id="result"' in page.text and '"three": "/static/vendor/three.module.js"' in page.text
    for name in ("app.js", "view.js", "plot.js", "pose.js", "api.js", "align.js", "style.css",
                 "vendor/three.module.js", "vendor/three.core.js", "vendor/OrbitControls.js"):  # fmt: skip
        assert client.get(f"/static/{name}").status_code == 200, name
    assert "MIT License" in client.get("/static/vendor/LICENSE").text
    missing = client.get("/static/../pyproject.toml")
    assert missing.status_code == 404 and missing.json()["kind"] == "not_found"


def test_examples_list_and_points(client):
    listed = client.get("/v1/examples").json()
    names = {e["name"]: e for e in listed["examples"]}
    assert {"chair_a", "chair_b", "chair_quarter_a", "chair_quarter_b"} <= set(names)
    points = client.get("/v1/examples/chair_a").json()["points"]
    assert np.array_equal(points, read_cloud(EXAMPLES / "chair_a.ply"))
    assert names["chair_a"]["points"] == len(points)
    pair = next(p for p in listed["pairs"] if p["name"] == "chair")
    truth = json.loads((EXAMPLES / "chair_truth.json").read_text())["T_b_from_a"]
    assert (pair["a"], pair["b"], pair["T_b_from_a"]) == ("chair_a", "chair_b", truth)
    # each pair names its category, so that the align tab can pick the model that fits it
    assert {p["name"]: p["category"] for p in listed["pairs"]}["bed"] == "bed"
    assert all(p["category"] == p["name"].split("_quarter")[0] for p in listed["pairs"])
    unknown = client.get("/v1/examples/nope")
    assert unknown.status_code == 404 and "chair_a" in unknown.json()["detail"]


def test_example_scenes_list_their_camera_and_serve_their_depth_image(client):
    (scene,) = client.get("/v1/examples").json()["scenes"]
    camera = json.loads((EXAMPLES / "scene_camera.json").read_text())
    truth = json.loads((EXAMPLES / "scene_truth.json").read_text())
    assert scene["name"] == "scene" and scene["file"] == "scene.png"
    assert scene["intrinsics"] == {k: camera[k] for k in ("fx", "fy", "cx", "cy")}
    assert scene["categories"] == [o["category"] for o in truth["objects"]]
    image = client.get("/v1/examples/scenes/scene")
    assert image.status_code == 200 and image.headers["content-type"] == "image/png"
    assert image.content == (EXAMPLES / "scene.png").read_bytes()
    unknown = client.get("/v1/examples/scenes/chair_a")
    assert unknown.status_code == 404 and "scene" in unknown.json()["detail"]


def _files(points: np.ndarray, tmp_path: Path) -> dict[str, bytes]:
    """The same cloud as .ply, .xyz and .npy bytes."""
    write_ply(tmp_path / "c.ply", points)
    text, npy = io.StringIO(), io.BytesIO()
    np.savetxt(text, points)
    np.save(npy, points)
    return {"c.ply": (tmp_path / "c.ply").read_bytes(), "c.xyz": text.getvalue().encode(),
            "c.npy": npy.getvalue()}  # fmt: skip


def test_a_dropped_file_is_read_like_the_cli_reads_it(client, tmp_path):
    points = read_cloud(EXAMPLES / "chair_b.ply")  # float32 values: exact in every format
    for name, data in _files(points, tmp_path).items():
        reply = client.post(f"/v1/clouds/read?filename={name}", content=data)
        assert reply.status_code == 200, (name, reply.text)
        assert reply.json()["count"] == len(points) and np.allclose(reply.json()["points"], points)


@pytest.mark.parametrize(
    ("filename", "body", "status", "says"),
    [
        ("scan.ply", b"ply\nformat ascii 1.0\n", 422, "scan.ply: no 'end_header'"),
        ("scan.doc", b"1 2 3\n", 422, "unknown format '.doc'"),
        ("scan.xyz", b"1 2 3\n" * 5, 422, "5 points is too few"),
        ("scan.xyz", b"1 2 3\n4 nan 6\n" * 40, 422, "NaN or infinite"),
        ("scan.xyz", b"1 2 3\n" * 2001, 422, "2001 points is too many"),
        ("scan.xyz", b"1 2 3\n" * 40_000, 413, "exceeds the limit"),
    ],
)
def test_a_bad_file_gets_a_clear_4xx(client, filename, body, status, says):
    reply = client.post(f"/v1/clouds/read?filename={filename}", content=body)
    assert reply.status_code == status and says in reply.json()["detail"], reply.text
    assert client.get("/healthz").status_code == 200


def test_align_is_the_in_process_alignment_with_the_loaded_model(client, tiny_model_dir):
    from itnet.alignment.estimators import in_process_estimator
    from itnet.alignment.pipeline import align_clouds
    from itnet.alignment.request import AlignRequest
    from itnet.pose.catalog import Catalog
    from itnet.pose.runtime import load_models

    a, b = read_cloud(EXAMPLES / "chair_a.ply"), read_cloud(EXAMPLES / "chair_b.ply")
    body = {"points_a": a.tolist(), "points_b": b.tolist(), "refine": False, "budget_ms": 2000}
    reply = client.post("/v1/align", json=body)
    assert reply.status_code == 200, reply.text
    got = reply.json()
    catalog = Catalog(load_models(tiny_model_dir, warm_up=False))
    request = AlignRequest(model="tiny", budget_ms=2000)
    options = request.options(catalog.model("tiny").card, refine=False)
    want = align_clouds(a, b, in_process_estimator(catalog, request.pose_request()), options)
    assert got["model"] == "tiny" and got["refined"] is False
    assert np.allclose(got["T_b_from_a"], want.T_b_from_a, atol=1e-9)
    assert got["hypothesis"] == want.hypotheses[want.chosen].source
    # each cloud's served pose: 4 fused runs of the tiny model's 5 steps
    assert got["iterations"] == want.iterations == 10


def test_align_with_each_clouds_up_holds_both_poses_upright(client):
    from itnet.upright import unit_up

    a, b = read_cloud(EXAMPLES / "chair_a.ply"), read_cloud(EXAMPLES / "chair_b.ply")
    ups = {"up_a": [0.1, -1.0, 0.2], "up_b": [0.0, 0.0, 2.0]}
    body = {"points_a": a.tolist(), "points_b": b.tolist(), "refine": False, "budget_ms": 2000}
    reply = client.post("/v1/align", json=body | ups)
    assert reply.status_code == 200, reply.text
    got = reply.json()
    for cloud in "ab":
        pose = np.array(got[f"T_canonical_from_{cloud}"]["T_canonical_from_input"])
        assert np.allclose(pose[:3, :3] @ unit_up(ups[f"up_{cloud}"]), [0, 1, 0], atol=1e-4)
        assert got[f"up_{cloud}"] == ups[f"up_{cloud}"]
    t = np.array(got["T_b_from_a"])
    assert np.allclose(t[:3, :3] @ unit_up(ups["up_a"]), unit_up(ups["up_b"]), atol=1e-3)


@pytest.mark.parametrize(
    ("change", "status", "says"),
    [
        ({"up_a": [0, 0, 0]}, 422, "zero vector"),
        ({"up_b": [0, 1]}, 422, "up_b"),
        ({"points_a": [[0, 0, 0]] * 5}, 422, "cloud A: 5 points is too few"),
        ({"points_b": [[1, 1, 1]] * 64}, 422, "cloud B:"),  # degenerate: all points equal
        ({"budget_ms": 60_000}, 422, "over the limit"),
        ({"model": "mug"}, 404, "unknown model 'mug'"),
        ({"starts": 0}, 422, "starts"),
        ({"extra": 1}, 422, "extra"),
    ],
)
def test_align_refuses_bad_requests(client, change, status, says):
    points = read_cloud(EXAMPLES / "chair_a.ply").tolist()
    reply = client.post("/v1/align", json={"points_a": points, "points_b": points, **change})
    assert reply.status_code == status and says in reply.json()["detail"], reply.text
    assert client.post("/v1/align", content=b"{").status_code == 400
