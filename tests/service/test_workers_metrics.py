"""``itnet serve --workers 2``: the workers' metrics add up, whichever worker a scrape reaches,
and the folder they add up in goes when the server stops."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest

from benchmarks.harness import serve
from itnet.service.metrics import MULTIPROCESS_DIR_ENV, Metrics, forget_dead_workers

ESTIMATES_OK = re.compile(r'itnet_requests_total\{endpoint="/v1/estimate",status="200"\} (\S+)')


def test_metrics_of_several_workers_add_up(tiny_model_dir: Path, tmp_path: Path) -> None:
    cloud = np.random.default_rng(0).normal(size=(300, 3)).tolist()
    scratch = tmp_path / "tmp"  # the server's TMPDIR: where it makes the metrics folder
    scratch.mkdir()
    env = {"TMPDIR": str(scratch)}
    with serve(tiny_model_dir, tmp_path / "server.log", env, args=["--workers", "2"]) as server:
        assert len(list(scratch.glob("itnet-metrics-*"))) == 1
        for _ in range(12):  # a connection each: the kernel spreads them over the workers
            with httpx.Client(base_url=server.url, timeout=30) as client:
                reply = client.post("/v1/estimate", json={"points": cloud, "budget_ms": 50})
                assert reply.status_code == 200
        for _ in range(6):  # each scrape reaches either worker
            with httpx.Client(base_url=server.url, timeout=30) as client:
                text = client.get("/metrics").text
            assert [float(v) for v in ESTIMATES_OK.findall(text)] == [12.0], text
            assert re.search(r"^itnet_in_flight 0\.0$", text, re.MULTILINE), text
    assert list(scratch.glob("itnet-metrics-*")) == []


WORKER = """
import os, sys, time
from itnet.service.metrics import Metrics
metrics = Metrics()
metrics.in_flight.inc()
metrics.requests.labels("/v1/estimate", "200").inc()
print("ready", flush=True)
if sys.argv[1] == "die":
    os._exit(1)  # killed mid-request: no dec, no clean-up
time.sleep(60)
"""


def test_a_dead_workers_in_flight_is_forgotten_and_its_counts_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One worker dies mid-request, one is still running one: ``/metrics`` says one estimate is
    in flight (not two), and both requests stay counted."""
    folder = tmp_path / "metrics"
    folder.mkdir()
    env = {**os.environ, MULTIPROCESS_DIR_ENV: str(folder)}
    dead = subprocess.run([sys.executable, "-c", WORKER, "die"], env=env, capture_output=True)
    assert dead.returncode == 1 and b"ready" in dead.stdout, dead.stderr
    alive = subprocess.Popen(
        [sys.executable, "-c", WORKER, "live"], env=env, stdout=subprocess.PIPE
    )
    try:
        assert alive.stdout is not None and alive.stdout.readline().strip() == b"ready"
        assert len(list(folder.glob("gauge_livesum_*.db"))) == 2
        monkeypatch.setenv(MULTIPROCESS_DIR_ENV, str(folder))
        text = Metrics().render().decode()
        assert re.search(r"^itnet_in_flight 1\.0$", text, re.MULTILINE), text
        assert [float(v) for v in ESTIMATES_OK.findall(text)] == [2.0], text
        assert [p.name for p in folder.glob("gauge_livesum_*.db")] == [
            f"gauge_livesum_{alive.pid}.db"
        ]
        assert forget_dead_workers(str(folder)) == []  # the live one stays
    finally:
        alive.kill()
        alive.wait()
