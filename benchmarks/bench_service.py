"""End-to-end latency and throughput of the itnet service over loopback.

    python -m benchmarks.bench_service --model-dir itnet/models --requests 20 --duration-s 3

Starts ``uvicorn itnet.service.server:app_from_env`` on 127.0.0.1 (a free port), then measures:

1. latency for each budget (5/20/60 ms): client round trip vs the engine's own ``elapsed_ms``;
2. JSON vs binary (float32) bodies for a large cloud;
3. throughput with 1, 4 and 16 concurrent clients for a fixed time (bounded request count);
4. the accuracy mode (``ensemble``) as served: iterations reached and time, for each
   ``model:budget_ms:runs`` of ``--accuracy`` (runs ``default``: the card's, fitted to the budget),
   run first so that its first row's first request is the fresh server's first.

Prints markdown tables. Loopback only; the server is stopped at the end.
"""

from __future__ import annotations

import asyncio
import json
import os
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import typer

from benchmarks.harness import model_dir as harness_model_dir
from benchmarks.harness import percentile, serve

JSON = {"content-type": "application/json"}
BINARY = {"content-type": "application/octet-stream"}


def box_cloud(points: int, seed: int = 0) -> np.ndarray:
    """A noisy box surface in metres, 1.5 m in front of a camera (points x 3, float32)."""
    rng = np.random.default_rng(seed)
    cube = rng.uniform(-1, 1, size=(points, 3))
    axis = rng.integers(0, 3, size=points)
    cube[np.arange(points), axis] = np.sign(cube[np.arange(points), axis])
    return (cube * [0.25, 0.45, 0.25] + [0.1, -0.2, 1.5]).astype(np.float32)


def timed_posts(http: httpx.Client, body: bytes, headers: dict, params: dict, count: int) -> dict:
    """``count`` sequential POSTs after one warm-up: client ms, engine ms, iterations, the replies
    (JSON), and the warm-up's reply (``first``)."""
    first = http.post("/v1/estimate", content=body, headers=headers, params=params)
    first.raise_for_status()
    client_ms, replies = [], []
    for _ in range(count):
        start = time.perf_counter()
        reply = http.post("/v1/estimate", content=body, headers=headers, params=params)
        client_ms.append((time.perf_counter() - start) * 1e3)
        reply.raise_for_status()
        replies.append(reply.json())
    return {"client": client_ms, "engine": [r["elapsed_ms"] for r in replies],
            "iterations": [r["iterations"] for r in replies], "replies": replies,
            "first": first.json()}  # fmt: skip


def latency_table(url: str, cloud: np.ndarray, budgets: list[float], count: int) -> str:
    rows = ["| budget ms | iterations (median) | engine p50 / max ms | round trip p50 / p95 ms "
            "| overhead p50 ms |", "|---|---|---|---|---|"]  # fmt: skip
    with httpx.Client(base_url=url, timeout=30) as http:
        for budget in budgets:
            body = json.dumps({"points": cloud.tolist(), "budget_ms": budget,
                               "max_iterations": 200}).encode()  # fmt: skip
            r = timed_posts(http, body, JSON, {}, count)
            overhead = [c - e for c, e in zip(r["client"], r["engine"], strict=True)]
            rows.append(
                f"| {budget:g} | {np.median(r['iterations']):g} | {percentile(r['engine'], 50):.1f}"
                f" / {max(r['engine']):.1f} | {percentile(r['client'], 50):.1f} / "
                f"{percentile(r['client'], 95):.1f} | {percentile(overhead, 50):.1f} |"
            )
    return "\n".join(rows)


def body_table(url: str, cloud: np.ndarray, budget: float, count: int) -> str:
    rows = ["| body | points | bytes | round trip p50 / p95 ms | engine p50 ms | overhead p50 ms |",
            "|---|---|---|---|---|---|"]  # fmt: skip
    params = {"budget_ms": budget, "max_iterations": 200}
    bodies = {
        "JSON": (json.dumps({"points": cloud.tolist(), **params}).encode(), JSON, {}),
        "binary float32": (cloud.astype("<f4").tobytes(), BINARY, params),
    }
    with httpx.Client(base_url=url, timeout=30) as http:
        for name, (body, headers, query) in bodies.items():
            r = timed_posts(http, body, headers, query, count)
            overhead = [c - e for c, e in zip(r["client"], r["engine"], strict=True)]
            rows.append(
                f"| {name} | {len(cloud)} | {len(body):,} | {percentile(r['client'], 50):.1f} / "
                f"{percentile(r['client'], 95):.1f} | {percentile(r['engine'], 50):.1f} | "
                f"{percentile(overhead, 50):.1f} |"
            )
    return "\n".join(rows)


async def load(url: str, body: bytes, clients: int, duration_s: float, cap: int) -> dict:
    """``clients`` loops posting ``body`` until ``duration_s`` or ``cap`` requests in all."""
    latencies: list[float] = []
    iterations: list[int] = []
    statuses: dict[int, int] = {}
    stop = time.perf_counter() + duration_s
    started = 0

    async def client(http: httpx.AsyncClient) -> None:
        nonlocal started
        while time.perf_counter() < stop and started < cap:
            started += 1
            begin = time.perf_counter()
            reply = await http.post("/v1/estimate", content=body, headers=JSON)
            latencies.append((time.perf_counter() - begin) * 1e3)
            statuses[reply.status_code] = statuses.get(reply.status_code, 0) + 1
            if reply.status_code == 200:
                iterations.append(reply.json()["iterations"])

    limits = httpx.Limits(max_connections=clients)
    async with httpx.AsyncClient(base_url=url, timeout=30, limits=limits) as http:
        begin = time.perf_counter()
        await asyncio.gather(*(client(http) for _ in range(clients)))
        wall = time.perf_counter() - begin
    return {"latencies": latencies, "iterations": iterations, "statuses": statuses, "wall": wall}


def throughput_table(url: str, cloud: np.ndarray, budget: float, concurrency: list[int],
                     duration_s: float, cap: int) -> str:  # fmt: skip
    rows = ["| clients | requests | ok/s | 503 | iterations (mean) | steps/s | p50 / p95 ms |",
            "|---|---|---|---|---|---|---|"]  # fmt: skip
    body = json.dumps({"points": cloud.tolist(), "budget_ms": budget, "max_iterations": 200})
    for clients in concurrency:
        r = asyncio.run(load(url, body.encode(), clients, duration_s, cap))
        ok = r["statuses"].get(200, 0)
        rows.append(
            f"| {clients} | {sum(r['statuses'].values())} | {ok / r['wall']:.1f} | "
            f"{r['statuses'].get(503, 0)} | {np.mean(r['iterations']):.1f} | "
            f"{sum(r['iterations']) / r['wall']:.0f} | {percentile(r['latencies'], 50):.1f} / "
            f"{percentile(r['latencies'], 95):.1f} |"
        )
    return "\n".join(rows)


def accuracy_table(url: str, cloud: np.ndarray, cases: list[tuple[str, float, int | None]],
                   count: int) -> str:  # fmt: skip
    """The accuracy mode through the server: per (model, budget, runs or None for the card's
    default) case, ``count`` sequential requests; the very first one is reported apart."""
    rows = ["| model | budget ms | runs asked | runs used | iterations median (min) | "
            "engine p50 / max ms | round trip p50 ms | first request: iterations, ms |",
            "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    with httpx.Client(base_url=url, timeout=30) as http:
        for model, budget, runs in cases:
            request = {"points": cloud.tolist(), "budget_ms": budget, "model": model}
            if runs is not None:
                request["ensemble"] = runs
            r = timed_posts(http, json.dumps(request).encode(), JSON, {}, count)
            iterations, engine, first = r["iterations"], r["engine"], r["first"]
            used = sorted({reply.get("ensemble") or 1 for reply in r["replies"]})
            rows.append(
                f"| {model} | {budget:g} | {runs or 'default'} | {'/'.join(map(str, used))} | "
                f"{np.median(iterations):g} ({min(iterations)}) | {percentile(engine, 50):.1f} / "
                f"{max(engine):.1f} | {percentile(r['client'], 50):.1f} | {first['iterations']}, "
                f"{first['elapsed_ms']:.1f} |"
            )
    return "\n".join(rows)


def parse_cases(text: str) -> list[tuple[str, float, int | None]]:
    """``'chair:50:8,bathtub:20:default'`` -> [('chair', 50.0, 8), ('bathtub', 20.0, None)]."""
    cases = []
    for item in filter(None, text.split(",")):
        model, budget, runs = item.split(":")
        cases.append((model, float(budget), None if runs == "default" else int(runs)))
    return cases


def main(
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    points: int = typer.Option(2048, help="Points in the latency/throughput cloud."),
    large_points: int = typer.Option(50_000, help="Points in the JSON-vs-binary cloud."),
    budgets: str = typer.Option("5,20,60", help="Budgets for the latency table, ms."),
    concurrency: str = typer.Option("1,4,16", help="Concurrent clients for throughput."),
    throughput_budget_ms: float = typer.Option(20.0, help="Budget of the throughput requests."),
    requests: int = typer.Option(20, min=1, help="Sequential requests per latency row."),
    duration_s: float = typer.Option(3.0, min=0.1, help="Seconds per throughput row."),
    max_requests: int = typer.Option(2000, min=1, help="Request cap per throughput row."),
    threads: int = typer.Option(2, min=1, help="onnxruntime threads per model (ITNET_THREADS)."),
    accuracy: str = typer.Option(
        "chair:50:8,chair:20:4,chair:20:8,bathtub:50:default,bathtub:20:default,bed:50:default",
        help="Accuracy-mode cases, model:budget_ms:runs (runs 'default': the card's); cases of "
        "models the server has not loaded are skipped; '' for none.",
    ),
) -> None:
    """Measure the service over loopback and print markdown tables."""
    budget_list = [float(b) for b in budgets.split(",")]
    clients = [int(c) for c in concurrency.split(",")]
    load1, _, _ = os.getloadavg()
    typer.echo(f"machine: {os.cpu_count()} CPUs, load average {load1:.2f} at start; "
               f"ITNET_THREADS={threads}\n")  # fmt: skip
    env = {"ITNET_THREADS": str(threads),
           "ITNET_LIMITS__MAX_CONCURRENT_REQUESTS": str(max(clients) + 4)}  # fmt: skip
    log = Path(tempfile.gettempdir()) / "itnet-bench-service.log"
    with serve(harness_model_dir(model_dir), log, env) as server:
        url = server.url
        listing = httpx.get(f"{url}/v1/models").json()
        model = next(m for m in listing["models"] if m["name"] == listing["default_model"])
        typer.echo(f"default model: {model['name']} ({model['points']} points, one step "
                   f"{model['step_ms']:.2f} ms at start-up)\n")  # fmt: skip
        cloud, large = box_cloud(points), box_cloud(large_points, seed=1)
        loaded = {m["name"] for m in listing["models"]}
        cases = [c for c in parse_cases(accuracy) if c[0] in loaded]
        if cases:
            typer.echo(f"### Accuracy mode ({points} points, JSON, {requests} requests each "
                       "after the first)\n")  # fmt: skip
            typer.echo(accuracy_table(url, cloud, cases, requests) + "\n")
        typer.echo(f"### Latency by budget ({points} points, JSON, {requests} requests each)\n")
        typer.echo(latency_table(url, cloud, budget_list, requests) + "\n")
        typer.echo(f"### JSON vs binary body (budget 20 ms, {requests} requests each)\n")
        typer.echo(body_table(url, large, 20.0, requests) + "\n")
        typer.echo(f"### Throughput ({points} points, budget {throughput_budget_ms:g} ms, "
                   f"{duration_s:g} s per row)\n")  # fmt: skip
        typer.echo(throughput_table(url, cloud, throughput_budget_ms, clients, duration_s,
                                    max_requests))  # fmt: skip


if __name__ == "__main__":
    typer.run(main)
