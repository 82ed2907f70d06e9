"""The Ray Serve application on a local Ray instance with 2 replicas: the service's API and
answers (poses, streams, scenes, alignments), both replicas used, the budget held, and no request lost when a replica is killed."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from itnet.cloud_io import read_cloud
from itnet.geometry import rotation_error_deg

pytestmark = [pytest.mark.ray, pytest.mark.slow]
EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"
EXAMPLE = EXAMPLES / "chair_a.ply"
REPLICA = "x-itnet-replica"


@pytest.fixture(scope="module")
def points() -> list[list[float]]:
    return read_cloud(EXAMPLE).astype(np.float32).tolist()


@pytest.fixture(scope="module")
def url(local_ray: None) -> Iterator[str]:
    from ray import serve

    from itnet.scale.serve_app import build_app
    from tests.scale.conftest import free_port

    port = free_port()
    serve.start(http_options={"host": "127.0.0.1", "port": port})
    serve.run(build_app({"replicas": 2, "threads": 1}), name="itnet", route_prefix="/")
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        serve.shutdown()


def pid_of(reply: httpx.Response) -> int:
    return int(reply.headers[REPLICA].rsplit("pid=", 1)[1])


def test_health_models_and_errors_are_the_services(url: str) -> None:
    with httpx.Client(base_url=url, timeout=30) as c:
        assert c.get("/healthz").json() == {"status": "ok"}
        ready = c.get("/readyz")
        assert ready.status_code == 200 and "chair" in ready.json()["models"]
        models = c.get("/v1/models").json()
        assert models["default_model"] == "chair"
        bad = c.post("/v1/estimate", json={"points": [[0.0, 0.0, 0.0]] * 3})
        assert bad.status_code == 422 and bad.json()["kind"] == "bad_cloud"
        unknown = c.post(
            "/v1/estimate", json={"points": [[0, 0, 1]] * 64, "model": "no-such-model"}
        )
        assert unknown.status_code == 404 and unknown.json()["kind"] == "unknown_model"
        huge = c.post(
            "/v1/estimate",
            content=b"\0" * (16 * 2**20 + 12),
            headers={"content-type": "application/octet-stream"},
        )
        assert huge.status_code == 413 and huge.json()["kind"] == "too_large"


def test_answers_equal_the_single_process_service(url: str, points: list) -> None:
    """Same cloud, same model, same iterations: the same pose (JSON and binary bodies)."""
    from fastapi.testclient import TestClient

    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    request = {"points": points, "budget_ms": 5000, "max_iterations": 10}
    with TestClient(create_app(Settings(threads=1))) as local:
        expected = local.post("/v1/estimate", json=request).json()
    body = np.asarray(points, dtype="<f4").tobytes()
    with httpx.Client(base_url=url, timeout=30) as c:
        as_json = c.post("/v1/estimate", json=request).json()
        binary = c.post(
            "/v1/estimate?budget_ms=5000&max_iterations=10",
            content=body,
            headers={"content-type": "application/octet-stream"},
        ).json()
    for got in (as_json, binary):
        assert got["iterations"] == expected["iterations"] == 10
        np.testing.assert_allclose(
            got["T_canonical_from_input"], expected["T_canonical_from_input"], atol=1e-6
        )


@pytest.mark.timing
def test_both_replicas_answer_within_the_budget(url: str, points: list) -> None:
    """4 clients at once (coroutines of one thread: threads would fight for the GIL), 40 ms
    budgets: both replicas answer with poses (a request the busy machine cannot serve in its
    budget is refused at once), and the budget holds: p90 within budget + 25 ms. (One ``itnet
    serve`` holds + 15 ms in tests/hardening; here two replicas, Ray's proxy and the client share
    the 2 cores, and a fresh-clone CI run measured p90 56 ms on a noisy 2-core host.)"""
    budget_ms, margin_ms = 40.0, 25.0

    async def load() -> list[httpx.Response]:
        async with httpx.AsyncClient(base_url=url, timeout=30) as http:

            async def client() -> list[httpx.Response]:
                request = {"points": points, "budget_ms": budget_ms}
                return [await http.post("/v1/estimate", json=request) for _ in range(10)]

            return [r for rs in await asyncio.gather(*(client() for _ in range(4))) for r in rs]

    replies = asyncio.run(load())
    # A reply is a pose, or a refusal at once where the machine cannot serve it in its budget:
    # never the start handed back as a pose.
    assert {r.status_code for r in replies} <= {200, 503}
    refused = [r for r in replies if r.status_code == 503]
    assert all(r.json()["kind"] == "overloaded" and "retry-after" in r.headers for r in refused)
    # Ray's router spreads the requests: each replica answers several (a reply of each kind
    # names the replica that sent it), and each gives poses.
    answered = [r.headers[REPLICA] for r in replies]
    assert len(set(answered)) == 2 and min(map(answered.count, set(answered))) >= 4, answered
    replies = [r for r in replies if r.status_code == 200]
    assert len(replies) >= 10 and all(r.json()["iterations"] >= 1 for r in replies)
    served = [r.headers[REPLICA] for r in replies]
    assert len(set(served)) == 2, (served, [r.headers[REPLICA] for r in refused])
    elapsed = np.array([r.json()["elapsed_ms"] for r in replies])
    assert np.percentile(elapsed, 90) <= budget_ms + margin_ms, np.sort(elapsed)[-10:]
    assert elapsed.max() <= budget_ms + 4 * margin_ms, np.sort(elapsed)[-10:]
    steps: dict[str, int] = {}
    for r in replies:
        steps[r.headers[REPLICA]] = steps.get(r.headers[REPLICA], 0) + r.json()["iterations"]
    assert min(steps.values()) > 0 and sum(steps.values()) >= len(replies), steps


def test_stream_through_the_gateway(url: str, points: list) -> None:
    from websockets.sync.client import connect

    ws_url = url.replace("http://", "ws://") + "/v1/estimate/stream"
    with connect(ws_url) as ws:
        ws.send(json.dumps({"points": points, "budget_ms": 1000, "max_iterations": 6}))
        messages = []
        while True:
            try:
                messages.append(json.loads(ws.recv(timeout=30)))
            except Exception:  # the server's close ends the stream
                break
    assert [m["iteration"] for m in messages[:-1]] == [1, 2, 3, 4, 5, 6]
    assert messages[-1]["type"] == "result" and messages[-1]["stopped_by"] == "max_iterations"


def test_scenes_and_alignments_through_the_gateway(url: str) -> None:
    """The example scene (a 16-bit PNG body) and the example chair pair come back from the
    replicas as the service answers them: the scene's three objects named as its truth, each
    posed; the pair aligned within 5 degrees of its truth; bad scenes refused as the service
    refuses them."""
    truth = json.loads((EXAMPLES / "scene_truth.json").read_text())
    camera = json.loads((EXAMPLES / "scene_camera.json").read_text())
    query = {k: camera[k] for k in ("fx", "fy", "cx", "cy")} | {"budget_ms": 2000}
    png = (EXAMPLES / "scene.png").read_bytes()
    pair = {"points_a": read_cloud(EXAMPLES / "chair_a.ply").tolist(),
            "points_b": read_cloud(EXAMPLES / "chair_b.ply").tolist(), "model": "chair",
            "budget_ms": 5000}  # fmt: skip
    with httpx.Client(base_url=url, timeout=60) as c:
        scene = c.post("/v1/scene", params=query, content=png,
                       headers={"content-type": "image/png"})  # fmt: skip
        no_camera = c.post("/v1/scene", content=png, headers={"content-type": "image/png"})
        aligned = c.post("/v1/align", json=pair)
    assert scene.status_code == 200 and REPLICA in scene.headers, scene.text
    objects = scene.json()["objects"]
    assert sorted(o["category"] for o in objects) == sorted(o["category"] for o in truth["objects"])
    assert all(o["T_canonical_from_input"] is not None for o in objects)
    assert no_camera.status_code == 422 and no_camera.json()["kind"] == "bad_scene"
    assert aligned.status_code == 200, aligned.text
    expected = np.array(json.loads((EXAMPLES / "chair_truth.json").read_text())["T_b_from_a"])
    got = np.array(aligned.json()["T_b_from_a"])
    assert rotation_error_deg(got[:3, :3], expected[:3, :3]) < 5.0


def test_a_killed_replica_loses_no_request(url: str, points: list) -> None:
    """4 clients send for as long as it takes; one replica's process is SIGKILLed mid-load.
    Every request is answered 200 in the end; a client retries only a 503 with Retry-After.
    Ray starts a new replica (a new pid), which then answers too."""
    stop = threading.Event()
    statuses: list[int] = []
    pids: list[tuple[float, int]] = []
    failures: list[str] = []

    def client() -> None:
        with httpx.Client(base_url=url, timeout=60) as c:
            while not stop.is_set():
                reply = c.post("/v1/estimate", json={"points": points, "budget_ms": 30})
                statuses.append(reply.status_code)
                if reply.status_code == 200:
                    pids.append((time.monotonic(), pid_of(reply)))
                elif reply.status_code == 503 and "retry-after" in reply.headers:
                    time.sleep(float(reply.headers["retry-after"]))  # the reply says: retry
                else:
                    failures.append(f"{reply.status_code} {reply.text[:200]}")

    threads = [threading.Thread(target=client) for _ in range(4)]
    for t in threads:
        t.start()
    try:
        deadline = time.monotonic() + 30
        while len({p for _, p in pids}) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        before = {p for _, p in pids}
        assert len(before) == 2
        victim = max(before)
        os.kill(victim, signal.SIGKILL)
        killed_at = time.monotonic()
        # Wait for the replacement replica to answer (Ray restarts it, models and all).
        while time.monotonic() < killed_at + 90:
            after = {p for t, p in pids if t > killed_at}
            if after - before:
                break
            time.sleep(0.2)
        time.sleep(1.0)
    finally:
        stop.set()
        for t in threads:
            t.join()
    assert failures == []
    after = {p for t, p in pids if t > killed_at}
    assert after - before, "no new replica answered after the kill"
    assert victim not in {p for t, p in pids if t > killed_at + 5}
    assert statuses.count(200) > 20


def test_the_config_file_builds_the_application() -> None:
    """deploy/ray/serve.yaml passes Serve's own schema, and its args build the app with an
    autoscaling range for the Estimator replicas."""
    import yaml
    from ray.serve.schema import ServeDeploySchema

    from itnet.scale.serve_app import ServeArgs, build_app

    config = yaml.safe_load(
        (Path(__file__).resolve().parents[2] / "deploy/ray/serve.yaml").read_text()
    )
    ServeDeploySchema.model_validate(config)  # raises on a field Serve does not know
    (app,) = config["applications"]
    assert app["import_path"] == "itnet.scale.serve_app:build_app"
    args = ServeArgs.model_validate(app["args"])
    scaling = args.scaling()["autoscaling_config"]
    assert (scaling["min_replicas"], scaling["max_replicas"]) == (2, 8)
    assert build_app(app["args"]) is not None
    with pytest.raises(ValueError):
        ServeArgs.model_validate({"min_replicas": 3})  # a range needs both ends
