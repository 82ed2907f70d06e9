"""``itnet serve --workers 2``: the workers' metrics add up, whichever worker a scrape reaches,
and the folder they add up in goes when the server stops."""

from __future__ import annotations

import re
from pathlib import Path

import httpx
import numpy as np

from benchmarks.harness import serve

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
