"""Shared pieces of the load, soak and fault tools: a model to serve, a real ``itnet serve``
process on a free loopback port, its resident memory, percentiles.

The model is the trained ``itnet/models/chair.onnx`` when it exists, else a stand-in with the
paper's architecture (64-128-1024 / 512-256) and random weights, exported once into
``cache/bench-standin/`` (a step costs what a trained model's step costs; the poses mean nothing).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import httpx
import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "itnet" / "models"
STANDIN = REPO / "cache" / "bench-standin"


def model_dir(chosen: Path | None = None) -> Path:
    """``chosen``, else the shipped models if chair.onnx is there, else the stand-in."""
    if chosen is not None:
        return chosen
    if (SHIPPED / "chair.onnx").is_file():
        return SHIPPED
    if not (STANDIN / "chair.onnx").is_file():
        export_standin(STANDIN)
    return STANDIN


def export_standin(folder: Path, seed: int = 0) -> Path:
    """A paper-sized IT-Net with random weights (last layer small but not the identity, so runs
    do not converge at once) exported as ``chair.onnx``. Needs the ``train`` extra (torch)."""
    import torch

    from itnet.export.onnx_export import export_step
    from itnet.model.network import ITNet, NetworkConfig
    from itnet.model_card import ModelCard

    torch.manual_seed(seed)
    net = ITNet(NetworkConfig())
    with torch.no_grad():
        net.regressor.out.weight.normal_(0, 0.001)
    folder.mkdir(parents=True, exist_ok=True)
    card = ModelCard(name="chair", category="chair", evaluation="random-weight stand-in")
    return export_step(net.eval(), card, folder / "chair.onnx")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def percentile(values: list[float] | np.ndarray, q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else float("nan")


def rss_mb(pid: int) -> float:
    """Resident memory of a process in MiB (Linux /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


@dataclass
class Server:
    url: str
    process: subprocess.Popen[bytes]
    log: IO[str]

    @property
    def port(self) -> int:
        return int(self.url.rsplit(":", 1)[1])

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://") + "/v1/estimate/stream"

    def rss_mb(self) -> float:
        return rss_mb(self.process.pid)

    def log_tail(self, chars: int = 3000) -> str:
        self.log.flush()
        self.log.seek(0)
        return self.log.read()[-chars:]


@contextmanager
def serve(
    models: Path,
    log_path: Path,
    env: Mapping[str, str] | None = None,
    timeout_s: float = 90,
    args: Sequence[str] = (),
    log_level: str = "warning",
) -> Iterator[Server]:
    """``itnet serve`` (plus ``args``) on a free loopback port until /readyz says 200; SIGTERM
    (then kill) on exit unless it has exited already. Used by the benchmarks and the tests that
    need a real server process."""
    port = free_port()
    command = [sys.executable, "-c", "from itnet.cli import app; app()", "serve",
               "--host", "127.0.0.1", "--port", str(port), "--model-dir", str(models),
               "--log-level", log_level, *args]  # fmt: skip
    log = log_path.open("w+")
    process = subprocess.Popen(
        command, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
    )
    server = Server(f"http://127.0.0.1:{port}", process, log)
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            if process.poll() is not None:
                raise RuntimeError(f"the server exited: {server.log_tail()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the server was not ready in {timeout_s} s")
            try:
                if httpx.get(f"{server.url}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        yield server
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=40)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=10)
        log.close()


def sample_cloud(points: int, seed: int = 0) -> np.ndarray:
    """A box-shaped partial-ish cloud (points, 3) in metres, 2 m in front of a camera."""
    rng = np.random.default_rng(seed)
    box = rng.uniform(-1, 1, size=(points, 3)) * [0.25, 0.45, 0.25]
    return (box + np.array([0.1, -0.2, 2.0])).astype(np.float32)
