"""A real ``itnet serve`` process on loopback, spoken to over HTTP and WebSocket."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from benchmarks.harness import serve

START_TIMEOUT_S = 60


@pytest.fixture(scope="module")
def server(tiny_model_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """``itnet serve`` on a free port; yields its base URL; stopped (then killed) at the end."""
    log = tmp_path_factory.mktemp("e2e") / "server.log"
    env = {"ITNET_THREADS": "1"}
    with serve(tiny_model_dir, log, env, timeout_s=START_TIMEOUT_S, log_level="info") as running:
        yield running.url


POINTS = np.random.default_rng(11).uniform(-0.5, 0.5, size=(700, 3)).astype(np.float32)


@pytest.mark.e2e
def test_http_json_binary_and_bad_input(server: str) -> None:
    with httpx.Client(base_url=server, timeout=10) as http:
        assert http.get("/healthz").json() == {"status": "ok"}
        assert [m["name"] for m in http.get("/v1/models").json()["models"]] == ["tiny"]
        by_json = http.post(
            "/v1/estimate", json={"points": POINTS.tolist(), "max_iterations": 3, "budget_ms": 5000}
        )
        assert by_json.status_code == 200 and by_json.json()["iterations"] == 3
        by_binary = http.post(
            "/v1/estimate",
            content=POINTS.astype("<f4").tobytes(),
            headers={"content-type": "application/octet-stream"},
            params={"max_iterations": 3, "budget_ms": 5000},
        )
        assert by_binary.status_code == 200
        np.testing.assert_allclose(
            by_binary.json()["T_canonical_from_input"],
            by_json.json()["T_canonical_from_input"],
            atol=1e-6,
        )
        bad = http.post("/v1/estimate", content=b"\0" * 13,
                        headers={"content-type": "application/octet-stream"})  # fmt: skip
        assert bad.status_code == 400 and "multiple of 12" in bad.json()["detail"]
        assert http.post("/v1/estimate", json={"points": POINTS.tolist()}).status_code == 200
        assert 'itnet_requests_total{endpoint="/v1/estimate",status="400"} 1.0' in (
            http.get("/metrics").text
        )


@pytest.mark.e2e
def test_websocket_stream_and_error(server: str) -> None:
    ws_url = server.replace("http://", "ws://") + "/v1/estimate/stream"
    with connect(ws_url, open_timeout=10, close_timeout=5) as ws:
        ws.send(json.dumps({"points": POINTS.tolist(), "budget_ms": 2000, "max_iterations": 4}))
        messages = [json.loads(ws.recv(timeout=10)) for _ in range(5)]
        with pytest.raises(ConnectionClosed):
            ws.recv(timeout=10)
    assert [m["type"] for m in messages] == ["estimate"] * 4 + ["result"]
    assert messages[-1]["iterations"] == 4
    assert messages[-1]["T_canonical_from_input"] == messages[-2]["T_canonical_from_input"]
    assert ws.close_code == 1000
    with connect(ws_url, open_timeout=10, close_timeout=5) as ws:
        ws.send('{"points": oops}')
        error = json.loads(ws.recv(timeout=10))
        with pytest.raises(ConnectionClosed):
            ws.recv(timeout=10)
    assert error["type"] == "error" and "malformed JSON" in error["detail"]
    assert ws.close_code == 1008
