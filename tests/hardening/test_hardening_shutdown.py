"""SIGTERM to ``itnet serve`` while requests run: the listening socket closes at once (new
connections are refused), the HTTP requests in flight finish with their full answer, streams in
flight are closed with 1012 (service restart) and their runs stop, and the process exits 0."""

from __future__ import annotations

import json
import signal
import socket
import threading
import time
from pathlib import Path

import httpx
import pytest
from hardening_helpers import wait_for
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from benchmarks.harness import serve


def refused(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
    except ConnectionRefusedError:
        return True
    return False


def in_flight(url: str) -> float:
    for line in httpx.get(f"{url}/metrics").text.splitlines():
        if line.startswith("itnet_in_flight "):
            return float(line.split()[1])
    raise AssertionError("no itnet_in_flight in /metrics")


def test_sigterm_drains_then_exits_0(heavy_model_dir: Path, tmp_path: Path, points: list) -> None:
    env = {"ITNET_THREADS": "1", "ITNET_SERVER__GRACEFUL_SHUTDOWN_S": "10"}
    with serve(heavy_model_dir, tmp_path / "server.log", env, log_level="info") as server:
        url = server.url
        request = {"points": points, "budget_ms": 1500, "max_iterations": 200}
        replies: list[tuple[httpx.Response, float]] = []

        def post() -> None:
            reply = httpx.post(f"{url}/v1/estimate", json=request, timeout=20)
            replies.append((reply, time.perf_counter()))

        posts = [threading.Thread(target=post) for _ in range(3)]
        for thread in posts:
            thread.start()
        stream = connect(server.ws_url, open_timeout=10)
        stream.send(json.dumps(request))
        assert json.loads(stream.recv(timeout=10))["type"] == "estimate"
        # Connections still in the kernel's accept queue are reset when the socket closes: wait
        # until every request has reached the app.
        assert wait_for(lambda: in_flight(url) == 4, 5)

        sent_at = time.perf_counter()
        server.process.send_signal(signal.SIGTERM)
        assert wait_for(lambda: refused(server.port), 1.0), "still accepting after SIGTERM"
        # The stream stops at its next step and gets its final result before the close.
        messages = []
        with pytest.raises(ConnectionClosed):
            while True:
                messages.append(json.loads(stream.recv(timeout=5)))
        *estimates, result = messages
        assert all(m["type"] == "estimate" for m in estimates)
        assert result["type"] == "result" and result["stopped_by"] == "cancelled"
        assert result["iterations"] == len(estimates) + 1 >= 2  # the first one read above
        assert stream.close_code == 1001
        for thread in posts:
            thread.join(timeout=15)
        assert [reply.status_code for reply, _ in replies] == [200, 200, 200]
        for reply, finished_at in replies:
            assert finished_at > sent_at  # in flight when the signal came, and answered in full
            body = reply.json()
            assert body["iterations"] > 0 and body["stopped_by"] in ("budget", "max_iterations")
            assert len(body["estimates"]) == body["iterations"]
        assert server.process.wait(timeout=15) == 0
        output = server.log_tail(chars=10**7)
    assert "Traceback" not in output, output[-3000:]


def _children(pid: int) -> list[int]:
    """PIDs whose parent is ``pid`` (from /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to list worker processes")
def test_sigterm_with_workers_stops_every_worker_and_exits_0(
    heavy_model_dir: Path, tmp_path: Path, points: list
) -> None:
    env = {"ITNET_THREADS": "1"}
    with serve(heavy_model_dir, tmp_path / "server.log", env, args=["--workers", "2"]) as server:
        pid = server.process.pid
        assert wait_for(lambda: len(_children(pid)) >= 2, 30), _children(pid)
        workers = _children(pid)
        request = {"points": points, "budget_ms": 200, "max_iterations": 3}
        for _ in range(4):
            reply = httpx.post(f"{server.url}/v1/estimate", json=request, timeout=20)
            assert reply.status_code == 200
        server.process.send_signal(signal.SIGTERM)
        assert server.process.wait(timeout=30) == 0
        assert wait_for(lambda: not any(Path(f"/proc/{p}").exists() for p in workers), 10)
        output = server.log_tail(chars=10**7)
    assert "Traceback" not in output, output[-3000:]
