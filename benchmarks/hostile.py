"""Hostile clients against ``itnet serve`` on loopback, bounded in time and count.

    python -m benchmarks.hostile                     # every scenario, ~3 minutes
    python -m benchmarks.hostile --only slowloris,uploads --seconds 8

Starts a real ``itnet serve`` with default limits, then runs each attack in a second process
while polite clients measure what they see (fresh connection per request; JSON, 2,048 points,
``budget_ms`` 50; in processes of their own, ``--per-process`` clients each, so that one client
loop's queueing is not counted as the server's) and this one samples the server's resident
memory (with its JSON parser's worker process) every 50 ms:

* ``slowloris``: 300 sockets send a request head a byte every 0.5 s, reconnecting when closed;
* ``idle_ws``: 1,000 WebSockets opened and left silent;
* ``ws_frames``: 30 WebSocket frames announcing 16 MiB, sent but for their last byte, stalled;
* ``uploads``: 40 uploads announcing 16 MiB, sent but for their last byte, stalled;
* ``huge_json``: 4 at once of a 16 MB JSON body with 2.1 million points;
* ``neighbour``: one client looping 250,000-point JSON bodies beside 2 binary clients;
* ``clients16`` / ``clients64``: closed-loop clients that honour ``Retry-After``.

Per scenario: the polite requests answered 200, those within budget + 5 ms (the server's
``elapsed_ms``, counted from the request's first byte), p99 of (client wall time - budget),
``/healthz`` answers, and RSS at start / peak / end (and after the attack, once it settles).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import multiprocessing
import os
import platform
import struct
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import typer

from benchmarks import slowloris
from benchmarks.harness import (
    ClientPlan,
    CpuMeter,
    model_dir,
    percentile,
    rss_mb,
    run_clients,
    sample_cloud,
    serve,
)

BUDGET_MS = 50.0
MIB = 2**20
WS_HEAD = (b"GET /v1/estimate/stream HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n"
           b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
           b"Sec-WebSocket-Version: 13\r\n\r\n")  # fmt: skip


async def _open(port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter] | None:
    try:
        return await asyncio.open_connection("127.0.0.1", port)
    except OSError:
        await asyncio.sleep(0.05)
        return None


async def _ws(port: int, stop: float, frame: bytes | None) -> None:
    """One WebSocket: handshake, then (optionally) ``frame``, then silence until ``stop``."""
    pair = await _open(port)
    if pair is None:
        return
    reader, writer = pair
    try:
        writer.write(WS_HEAD)
        await writer.drain()
        if not (await reader.readuntil(b"\r\n\r\n")).startswith(b"HTTP/1.1 101"):
            return  # refused: nothing to hold
        if frame is not None:  # after the 101, as RFC 6455 requires (before it: closed 1002)
            writer.write(frame)
            await writer.drain()
        while time.time() < stop and not reader.at_eof():
            try:
                await asyncio.wait_for(reader.read(65536), timeout=stop - time.time())
            except TimeoutError:
                break
    except (OSError, asyncio.IncompleteReadError):
        pass
    finally:
        writer.close()


async def _upload(port: int, stop: float, size: int) -> None:
    pair = await _open(port)
    if pair is None:
        return
    reader, writer = pair
    head = (f"POST /v1/estimate HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {size}\r\n\r\n").encode()  # fmt: skip
    try:
        writer.write(head)
        chunk = b" " * MIB
        for sent in range(0, size - 1, MIB):
            writer.write(chunk[: min(MIB, size - 1 - sent)])
            await writer.drain()
            if reader.at_eof():
                break
        while time.time() < stop and not reader.at_eof():
            try:
                await asyncio.wait_for(reader.read(65536), timeout=stop - time.time())
            except TimeoutError:
                break
    except OSError:
        pass
    finally:
        writer.close()


async def _post_loop(url: str, stop: float, body: bytes, concurrent: int) -> None:
    async with httpx.AsyncClient(base_url=url, timeout=60) as http:

        async def one() -> None:
            while time.time() < stop:
                try:
                    await http.post("/v1/estimate", content=body,
                                    headers={"content-type": "application/json"})  # fmt: skip
                except httpx.HTTPError:
                    await asyncio.sleep(0.05)

        await asyncio.gather(*(one() for _ in range(concurrent)))


def _frame_head(length: int) -> bytes:
    return bytes([0x81, 0x80 | 127]) + struct.pack("!Q", length) + b"\0\0\0\0"


def attack(name: str, url: str, seconds: float) -> None:
    """The attacker process: run scenario ``name`` for ``seconds``."""
    port, stop = int(url.rsplit(":", 1)[1]), time.time() + seconds

    async def run() -> None:
        if name == "slowloris":
            await slowloris.attack(port, 300, seconds, slowloris.request_head(100_000), 0.5, False)
        elif name == "idle_ws":
            await asyncio.gather(*(_ws(port, stop, None) for _ in range(1000)))
        elif name == "ws_frames":
            frame = _frame_head(16 * MIB) + b" " * (16 * MIB - 1)
            await asyncio.gather(*(_ws(port, stop, frame) for _ in range(30)))
        elif name == "uploads":
            await asyncio.gather(*(_upload(port, stop, 16 * MIB) for _ in range(40)))
        elif name == "huge_json":
            body = b'{"points": [' + b"[0,0,0]," * 2_100_000 + b"[0,0,0]]}"
            await _post_loop(url, stop, body, 4)
        elif name == "neighbour":
            cloud = sample_cloud(250_000, seed=3)
            await _post_loop(url, stop, json.dumps({"points": cloud.tolist()}).encode(), 1)

    asyncio.run(run())


def tree_rss_mb(pid: int) -> float:
    """RSS of the server and its child processes (the JSON parser's worker), MiB."""
    total = rss_mb(pid)
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            with contextlib.suppress(OSError, RuntimeError):
                total += rss_mb(int(child))
    return total


class RssSampler:
    """The server's RSS (with its children) every ``every_s`` in a thread: start, peak, last."""

    def __init__(self, pid: int, every_s: float = 0.05) -> None:
        self.pid, self.every_s, self.samples = pid, every_s, [tree_rss_mb(pid)]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            self.samples.append(tree_rss_mb(self.pid))

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def summarise(name: str, result: dict, rss: list[float], settled: float, cpu: dict) -> dict:
    rows, health = result["rows"], result["health"]
    ok = [r for r in rows if r[0] == 200]
    late = [r for r in ok if r[2] > BUDGET_MS + 5]  # where: before the first step, or after
    wall = np.array([r[1] - BUDGET_MS for r in ok])
    within = sum(r[2] <= BUDGET_MS + 5 for r in ok)
    return {
        "scenario": name,
        "requests": len(rows),
        "ok": len(ok),
        "client_processes": result["processes"],
        "statuses": {str(s): sum(r[0] == s for r in rows) for s in sorted({r[0] for r in rows})},
        "ok_within_budget_5ms": within,
        "wall_minus_budget_p99_ms": percentile(wall, 99),
        "elapsed_minus_budget_p99_ms": percentile([r[2] - BUDGET_MS for r in ok], 99),
        "elapsed_p99_ms": percentile([r[2] for r in ok], 99),
        "late_5ms_before_first_step_in_step_after_last": [
            sum(r[3] == 0 for r in late),
            sum(r[3] > 0 and r[4] > BUDGET_MS + 5 for r in late),
            sum(r[3] > 0 and r[4] <= BUDGET_MS + 5 for r in late),
        ],
        "healthz_ok": f"{health.count(200)}/{len(health)}",
        **cpu,
        "client_cores": result["client_cores"],
        "rss_start_peak_end_settled_mib": [round(v) for v in (rss[0], max(rss), rss[-1], settled)],
    }


SCENARIOS: dict[str, tuple[int, bool]] = {  # name -> (polite clients, binary bodies)
    "slowloris": (1, False), "idle_ws": (1, False), "ws_frames": (1, False),
    "uploads": (1, False), "huge_json": (1, False), "neighbour": (2, True),
    "clients16": (16, False), "clients64": (64, False),
}  # fmt: skip


def settle(pid: int, start_mib: float, limit_s: float) -> float:
    """Wait (at most ``limit_s``) until the RSS is within 25% of ``start_mib``; the RSS then."""
    deadline = time.monotonic() + limit_s
    while tree_rss_mb(pid) > 1.25 * start_mib and time.monotonic() < deadline:
        time.sleep(0.5)
    return tree_rss_mb(pid)


def main(
    only: str = typer.Option(",".join(SCENARIOS), help="Scenarios to run, comma-separated."),
    seconds: float = typer.Option(10.0, help="Seconds per scenario."),
    settle_s: float = typer.Option(60.0, help="At most this long for the RSS to come back."),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped or stand-in)."),
    json_out: Path | None = typer.Option(None, help="Write the rows as JSON here."),
    per_process: int = typer.Option(4, help="Polite clients per client process."),
) -> None:
    """Run the hostile-client scenarios and print one row each."""
    cloud = sample_cloud(2048)
    json_body = json.dumps({"points": cloud.tolist(), "budget_ms": BUDGET_MS}).encode()
    spawn = multiprocessing.get_context("spawn")
    rows = []
    with serve(model_dir(models), Path("/tmp/itnet-hostile-server.log")) as server:
        for name in only.split(","):
            clients, binary = SCENARIOS[name]
            attacker, sampler = None, RssSampler(server.process.pid)  # start: before the attack
            meter = CpuMeter(server.process.pid)
            with sampler:
                if not name.startswith("clients"):
                    attacker = spawn.Process(target=attack, args=(name, server.url, seconds + 4))
                    attacker.start()
                    time.sleep(1.0)  # let the attack build up (the clients start ~2 s later)
                plan = ClientPlan(server.url, json_body, fresh=True)  # honours Retry-After
                if binary:
                    plan = ClientPlan(server.url, cloud.astype("<f4").tobytes(),
                                      "application/octet-stream", {"budget_ms": str(BUDGET_MS)},
                                      fresh=True)  # fmt: skip
                meter.start()
                result = run_clients(plan, clients, seconds - 1, per_process, probe=True)
                cpu = meter.stop()
                if attacker is not None:
                    attacker.join(timeout=30)
            settled = settle(server.process.pid, sampler.samples[0], settle_s)
            rows.append(summarise(name, result, sampler.samples, settled, cpu))
            typer.echo(json.dumps(rows[-1]), err=True)
    typer.echo(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}"
    )
    typer.echo("| scenario | polite requests | 200 | within budget+5 ms | wall-budget p99 ms "
               "| elapsed-budget p99 ms | /healthz 200 | RSS start / peak / end / settled MiB |")  # fmt: skip
    typer.echo("|---|---|---|---|---|---|---|---|")
    for r in rows:
        typer.echo(f"| {r['scenario']} | {r['requests']} | {r['ok']} | "
                   f"{r['ok_within_budget_5ms']} | {r['wall_minus_budget_p99_ms']:+.1f} | "
                   f"{r['elapsed_minus_budget_p99_ms']:+.1f} | "
                   f"{r['healthz_ok']} | {' / '.join(map(str, r['rss_start_peak_end_settled_mib']))} |")  # fmt: skip
    if json_out is not None:
        json_out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    typer.run(main)
