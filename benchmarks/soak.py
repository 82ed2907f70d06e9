"""Soak test of ``itnet serve``: a steady mixed load for minutes while the server's memory is
sampled; the resident set must stop growing once warm.

    python -m benchmarks.soak                       # 10 minutes, 4 clients
    python -m benchmarks.soak --duration-s 60 --sample-s 5

Each client loops over a mix of requests: JSON estimates, binary estimates, WebSocket streams
(half of them cancelled after the first estimate, some abandoned mid-stream), bad requests (a
malformed body, NaN, too few points, an unknown model) and POSTs abandoned by a 20 ms client
timeout. The server's RSS is read from /proc every ``--sample-s`` seconds. Verdict: the growth
from the end of the warm-up (``--warm-up-s``) to the end, and the least-squares slope over that
span, must stay under ``--max-growth-mib``. Prints the samples and the verdict.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import random
import time
from pathlib import Path

import httpx
import numpy as np
import typer
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, WebSocketException

from benchmarks.harness import Server, model_dir, sample_cloud, serve

JSON = {"content-type": "application/json"}
BINARY = {"content-type": "application/octet-stream"}


class Mix:
    """The requests of the soak, and a count of what each got."""

    def __init__(self, points: int, budget_ms: float) -> None:
        cloud = sample_cloud(points)
        self.json = json.dumps({"points": cloud.tolist(), "budget_ms": budget_ms}).encode()
        self.binary = cloud.astype("<f4").tobytes()
        self.bad = [b'{"points": [[1, 2, 3]', b'{"points": [[NaN, 0, 0]]}',
                    json.dumps({"points": cloud[:5].tolist()}).encode(),
                    json.dumps({"points": cloud.tolist(), "model": "sofa"}).encode()]  # fmt: skip
        self.params = {"budget_ms": budget_ms}
        self.counts: dict[str, int] = {}

    def count(self, what: str) -> None:
        self.counts[what] = self.counts.get(what, 0) + 1

    async def one(self, http: httpx.AsyncClient, server: Server, rng: random.Random) -> None:
        pick = rng.random()
        if pick < 0.55:
            reply = await http.post("/v1/estimate", content=self.json, headers=JSON)
            self.count(f"json {reply.status_code}")
        elif pick < 0.70:
            reply = await http.post("/v1/estimate", content=self.binary, headers=BINARY,
                                    params=self.params)  # fmt: skip
            self.count(f"binary {reply.status_code}")
        elif pick < 0.85:
            await self.stream(server, cancel=rng.random() < 0.5, abandon=rng.random() < 0.2)
        elif pick < 0.95:
            reply = await http.post("/v1/estimate", content=rng.choice(self.bad), headers=JSON)
            self.count(f"bad {reply.status_code}")
        else:
            try:
                await http.post("/v1/estimate", content=self.json, headers=JSON, timeout=0.02)
                self.count("abandoned but answered")
            except httpx.TimeoutException:
                self.count("abandoned")

    async def stream(self, server: Server, cancel: bool, abandon: bool) -> None:
        async with connect(server.ws_url, open_timeout=10, close_timeout=2) as ws:
            await ws.send(self.json.decode())
            message = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if abandon and message["type"] == "estimate":
                self.count("stream abandoned")
                return
            if cancel and message["type"] == "estimate":
                with contextlib.suppress(ConnectionClosed):  # it may have finished meanwhile
                    await ws.send('{"type": "cancel"}')
            while message["type"] == "estimate":
                message = json.loads(await asyncio.wait_for(ws.recv(), 10))
            self.count(f"stream {message.get('stopped_by') or message.get('kind')}")


async def soak(server: Server, mix: Mix, clients: int, duration_s: float, sample_s: float) -> list:
    samples: list[tuple[float, float, int]] = []  # seconds, RSS MiB, requests so far
    start = time.perf_counter()
    stop = start + duration_s

    async def client(seed: int) -> None:
        rng = random.Random(seed)
        async with httpx.AsyncClient(base_url=server.url, timeout=30) as http:
            while time.perf_counter() < stop:
                try:
                    await mix.one(http, server, rng)
                except (httpx.HTTPError, WebSocketException, OSError, TimeoutError) as err:
                    mix.count(f"client error {type(err).__name__}")

    async def sampler() -> None:
        while time.perf_counter() < stop:
            samples.append((time.perf_counter() - start, server.rss_mb(), sum(mix.counts.values())))
            await asyncio.sleep(sample_s)

    await asyncio.gather(sampler(), *(client(seed) for seed in range(clients)))
    samples.append((time.perf_counter() - start, server.rss_mb(), sum(mix.counts.values())))
    return samples


def main(
    duration_s: float = typer.Option(600.0, help="Length of the soak, seconds."),
    clients: int = typer.Option(4, help="Concurrent clients."),
    sample_s: float = typer.Option(10.0, help="RSS sampling period, seconds."),
    warm_up_s: float = typer.Option(60.0, help="Growth is measured from this time on."),
    max_growth_mib: float = typer.Option(20.0, help="Allowed RSS growth after the warm-up."),
    budget_ms: float = typer.Option(50.0, help="budget_ms of the estimates."),
    points: int = typer.Option(2048, help="Points per cloud."),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped or stand-in)."),
    log: Path = typer.Option(Path("/tmp/itnet-soak-server.log"), help="Server log file."),
    json_out: Path | None = typer.Option(None, help="Write samples and counts as JSON here."),
) -> None:
    """Run the soak and print the RSS samples and the verdict."""
    mix = Mix(points, budget_ms)
    with serve(model_dir(models), log, {"ITNET_THREADS": "2"}) as server:
        samples = asyncio.run(soak(server, mix, clients, duration_s, sample_s))
        health = httpx.get(f"{server.url}/healthz", timeout=5).status_code
        in_flight = [line for line in httpx.get(f"{server.url}/metrics").text.splitlines()
                     if line.startswith("itnet_in_flight ")]  # fmt: skip
    typer.echo("| t s | RSS MiB | requests |\n|---|---|---|")
    for seconds, rss, count in samples:
        typer.echo(f"| {seconds:.0f} | {rss:.1f} | {count} |")
    warm = [(t, rss) for t, rss, _ in samples if t >= warm_up_s]
    growth = warm[-1][1] - warm[0][1] if len(warm) > 1 else float("nan")
    slope = float(np.polyfit(*zip(*warm), 1)[0]) * 600 if len(warm) > 2 else float("nan")
    total = sum(mix.counts.values())
    typer.echo(f"requests: {total} in {samples[-1][0]:.0f} s ({total / samples[-1][0]:.1f}/s); "
               f"by outcome: {json.dumps(dict(sorted(mix.counts.items())))}")  # fmt: skip
    typer.echo(f"RSS after warm-up {warm[0][1]:.1f} MiB -> end {warm[-1][1]:.1f} MiB "
               f"(growth {growth:+.1f} MiB, slope {slope:+.1f} MiB per 10 min, max "
               f"{max(r for _, r, _ in samples):.1f} MiB); /healthz {health}; {in_flight[0]}")  # fmt: skip
    held = abs(growth) <= max_growth_mib and slope <= max_growth_mib and health == 200
    typer.echo(f"verdict: {'no memory growth' if held else 'MEMORY GROWS or unhealthy'}")
    if json_out is not None:
        json_out.write_text(json.dumps({"samples": samples, "counts": mix.counts}, indent=1))
    if not held:
        raise typer.Exit(1)


if __name__ == "__main__":
    typer.run(main)
