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
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

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


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class CpuMeter:
    """The machine's busy share (all cores, from /proc/stat) and the CPU seconds of ``pids``
    (with their child processes) between ``start()`` and ``stop()``."""

    def __init__(self, pid: int) -> None:
        self.pid = pid

    @staticmethod
    def _machine() -> tuple[int, int]:
        ticks = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
        return sum(ticks), ticks[3] + ticks[4]  # total, idle + iowait

    def _tree(self) -> float:
        total = cpu_seconds(self.pid)
        for task in Path(f"/proc/{self.pid}/task").iterdir():
            for child in (task / "children").read_text().split():
                with suppress(OSError, ValueError):
                    total += cpu_seconds(int(child))
        return total

    def start(self) -> None:
        self._t0, self._m0, self._s0 = time.perf_counter(), self._machine(), self._tree()

    def stop(self) -> dict[str, float]:
        (total, idle), seconds = self._machine(), time.perf_counter() - self._t0
        busy = 1 - (idle - self._m0[1]) / max(1, total - self._m0[0])
        return {"machine_busy_share": round(busy, 3),
                "server_cores": round((self._tree() - self._s0) / seconds, 2)}  # fmt: skip


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


# Closed-loop clients in separate processes (``run_clients``): one asyncio loop serving 64
# clients on the server's two cores would measure its own queueing as the server's.
# A row per reply: (status, client wall ms, server elapsed_ms or nan, iterations, when the last
# step ended, when the first step ended: both ms since the request arrived, 0 without a step).
Row = tuple[int, float, float, int, float, float]


def answered_row(data: dict, ms: float) -> Row:
    """A 200's row from its reply ``data`` and the client's wall time ``ms``."""
    steps = [e["elapsed_ms"] for e in data["estimates"]]
    return (200, ms, data["elapsed_ms"], data["iterations"], steps[-1] if steps else 0.0,
            steps[0] if steps else 0.0)  # fmt: skip


def failed_row(status: int, ms: float) -> Row:
    """A refusal's (or a transport error's: status 0) row."""
    return (status, ms, float("nan"), 0, 0.0, 0.0)


@dataclass(frozen=True)
class ClientPlan:
    url: str
    body: bytes
    content_type: str = "application/json"
    params: Mapping[str, str] | None = None  # query string (binary bodies)
    fresh: bool = False  # a new TCP connection per request
    retry_s: float | None = None  # after a 503: None honours Retry-After, else this long
    cap: int = 10**9  # requests per process (at most)
    threaded: bool = False  # a thread per client with a synchronous httpx.Client (else asyncio)


async def _client_loop(plan: ClientPlan, clients: int, start: float, stop: float,
                       probe: bool) -> dict:  # fmt: skip
    import asyncio

    rows: list[Row] = []
    health: list[int] = []
    limits = httpx.Limits(max_keepalive_connections=0 if plan.fresh else clients)
    await asyncio.sleep(max(0.0, start - time.time()))

    async def client(http: httpx.AsyncClient) -> None:
        while time.time() < stop and len(rows) < plan.cap:
            begin = time.perf_counter()
            try:
                reply = await http.post("/v1/estimate", content=plan.body, params=plan.params,
                                        headers={"content-type": plan.content_type})  # fmt: skip
            except httpx.HTTPError:
                rows.append(failed_row(0, (time.perf_counter() - begin) * 1e3))
                await asyncio.sleep(0.05)
                continue
            ms = (time.perf_counter() - begin) * 1e3
            if reply.status_code == 200:
                rows.append(answered_row(reply.json(), ms))
                continue
            rows.append(failed_row(reply.status_code, ms))
            if reply.status_code == 503:
                wait = plan.retry_s
                await asyncio.sleep(float(reply.headers.get("retry-after", 1)) if wait is None
                                    else wait)  # fmt: skip

    async def prober(http: httpx.AsyncClient) -> None:
        while time.time() < stop:
            try:
                health.append((await http.get("/healthz", timeout=5)).status_code)
            except httpx.HTTPError:
                health.append(0)
            await asyncio.sleep(0.1)

    async with httpx.AsyncClient(base_url=plan.url, timeout=60, limits=limits) as http:
        await asyncio.gather(*(client(http) for _ in range(clients)),
                             *([prober(http)] if probe else []))  # fmt: skip
    return {"rows": rows, "health": health}


def _client_threads(plan: ClientPlan, clients: int, start: float, stop: float) -> dict:
    """``clients`` threads, each a synchronous ``httpx.Client`` in a closed loop, as many users
    write them: send, read, send again at once; after a 503 wait ``retry_s`` (or Retry-After)."""
    import threading

    rows: list[Row] = []
    lock = threading.Lock()

    def client() -> None:
        with httpx.Client(base_url=plan.url, timeout=60) as http:
            time.sleep(max(0.0, start - time.time()))
            while time.time() < stop and len(rows) < plan.cap:
                begin = time.perf_counter()
                try:
                    reply = http.post("/v1/estimate", content=plan.body, params=plan.params,
                                      headers={"content-type": plan.content_type})  # fmt: skip
                except httpx.HTTPError:
                    with lock:
                        rows.append(failed_row(0, (time.perf_counter() - begin) * 1e3))
                    time.sleep(0.05)
                    continue
                ms = (time.perf_counter() - begin) * 1e3
                if reply.status_code == 200:
                    row = answered_row(reply.json(), ms)
                    with lock:
                        rows.append(row)
                    continue
                with lock:
                    rows.append(failed_row(reply.status_code, ms))
                if reply.status_code == 503:
                    wait = plan.retry_s
                    time.sleep(float(reply.headers.get("retry-after", 1)) if wait is None
                               else wait)  # fmt: skip

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return {"rows": rows, "health": []}


def _client_process(plan: ClientPlan, clients: int, start: float, stop: float, probe: bool,
                    out: Any) -> None:  # fmt: skip
    import asyncio
    import resource

    if plan.threaded:
        result = _client_threads(plan, clients, start, stop)
    else:
        result = asyncio.run(_client_loop(plan, clients, start, stop, probe))
    usage = resource.getrusage(resource.RUSAGE_SELF)
    out.put({**result, "cpu_s": usage.ru_utime + usage.ru_stime, "ended": time.time()})


def run_clients(plan: ClientPlan, clients: int, seconds: float, per_process: int = 4,
                probe: bool = False) -> dict:  # fmt: skip
    """``clients`` closed loops for ``seconds``, ``per_process`` to a process (the first one
    also asks /healthz every 0.1 s when ``probe``) -> rows, /healthz statuses, seconds: the
    time the clients ran, shorter than ``seconds`` where every process reached ``plan.cap``
    requests first (the rates are counted over it)."""
    import multiprocessing

    spawn = multiprocessing.get_context("spawn")
    out = spawn.Queue()
    counts = [min(per_process, clients - i) for i in range(0, clients, per_process)]
    start = time.time() + 1.5 + 0.1 * len(counts)  # every process imported and waiting
    stop = start + seconds
    processes = [spawn.Process(target=_client_process, args=(plan, n, start, stop,
                                                             probe and i == 0, out))
                 for i, n in enumerate(counts)]  # fmt: skip
    for process in processes:
        process.start()
    results = [out.get(timeout=seconds + 120) for _ in processes]
    for process in processes:
        process.join(timeout=10)
    ran = max(1e-3, min(seconds, max(res["ended"] for res in results) - start))
    return {"rows": [r for res in results for r in res["rows"]],
            "health": [h for res in results for h in res["health"]],
            "seconds": ran, "processes": len(processes),
            "client_cores": round(sum(res["cpu_s"] for res in results) / ran, 2)}  # fmt: skip
