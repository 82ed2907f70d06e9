"""Load test of ``itnet serve`` on loopback: latency, throughput and the budget under concurrency.

    python benchmarks/load_test.py                                  # 1, 4, 16, 64 clients
    python benchmarks/load_test.py --concurrency 1,4,16 --duration-s 20 --budget-ms 50

Starts a real ``itnet serve`` (uvicorn, the CLI's settings) on a free loopback port, then for
each client count runs that many closed-loop clients (each sends its next request as soon as its
last reply is in) for ``--duration-s`` seconds or ``--max-requests`` requests, whichever comes
first. Every request is a JSON cloud of ``--points`` points with ``budget_ms``.

Per row: replies by status (200, 503 = refused by the concurrency gate), throughput, client
round trip p50/p99, the engine's ``elapsed_ms`` (which starts when the request reaches the app)
p50/p99/max, and the overrun ``elapsed_ms - budget_ms`` at p99 and max. The budget holds when the
p99 overrun is within ``--margin-ms``. Prints a markdown table; ``--json-out`` saves the rows.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import httpx
import numpy as np
import typer

from benchmarks.harness import model_dir, percentile, sample_cloud, serve
from itnet.service.settings import Settings

JSON = {"content-type": "application/json"}


async def closed_loop(url: str, body: bytes, clients: int, duration_s: float, cap: int) -> dict:
    """``clients`` closed loops posting ``body``; every reply's status, latency and engine data."""
    # status, client ms, engine ms, iterations, engine ms when the last step ended (0: none)
    rows: list[tuple[int, float, float, int, float]] = []
    errors: dict[str, int] = {}
    stop, sent = time.perf_counter() + duration_s, 0
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)

    async def client(http: httpx.AsyncClient) -> None:
        nonlocal sent
        while time.perf_counter() < stop and sent < cap:
            sent += 1
            begin = time.perf_counter()
            try:
                reply = await http.post("/v1/estimate", content=body, headers=JSON)
            except httpx.HTTPError as err:
                errors[type(err).__name__] = errors.get(type(err).__name__, 0) + 1
                continue
            client_ms = (time.perf_counter() - begin) * 1e3
            if reply.status_code == 200:
                data = reply.json()
                last = data["estimates"][-1]["elapsed_ms"] if data["estimates"] else 0.0
                rows.append((200, client_ms, data["elapsed_ms"], data["iterations"], last))
            else:
                rows.append((reply.status_code, client_ms, float("nan"), 0, 0.0))
                if reply.status_code == 503:
                    await asyncio.sleep(0.01)  # a real client would honour Retry-After

    begin = time.perf_counter()
    async with httpx.AsyncClient(base_url=url, timeout=60, limits=limits) as http:
        await asyncio.gather(*(client(http) for _ in range(clients)))
    return {"rows": rows, "errors": errors, "seconds": time.perf_counter() - begin}


def summarise(result: dict, clients: int, budget_ms: float) -> dict:
    rows = result["rows"]
    ok = [r for r in rows if r[0] == 200]
    client_ms = [r[1] for r in ok]
    engine_ms = np.array([r[2] for r in ok])
    overrun = engine_ms - budget_ms
    statuses: dict[str, int] = {}
    for r in rows:
        statuses[str(r[0])] = statuses.get(str(r[0]), 0) + 1
    # Where each overrun (> 1 ms) arose: before any step (decoding, queueing), in a step that
    # took longer than predicted, or after the last step (handing the reply back).
    late = [r for r in ok if r[2] > budget_ms + 1]
    causes = {
        "before_first_step": sum(r[3] == 0 for r in late),
        "in_a_step": sum(r[3] > 0 and r[4] > budget_ms + 1 for r in late),
        "after_last_step": sum(r[3] > 0 and r[4] <= budget_ms + 1 for r in late),
    }
    return {
        "clients": clients,
        "requests": len(rows) + sum(result["errors"].values()),
        "statuses": statuses,
        "transport_errors": result["errors"],
        "ok_per_s": len(ok) / result["seconds"],
        "client_p50_ms": percentile(client_ms, 50),
        "client_p99_ms": percentile(client_ms, 99),
        "engine_p50_ms": percentile(engine_ms, 50),
        "engine_p99_ms": percentile(engine_ms, 99),
        "engine_max_ms": float(engine_ms.max()) if len(ok) else float("nan"),
        "overrun_p99_ms": percentile(overrun, 99),
        "overrun_max_ms": float(overrun.max()) if len(ok) else float("nan"),
        "iterations_mean": float(np.mean([r[3] for r in ok])) if ok else float("nan"),
        "zero_iteration_share": float(np.mean([r[3] == 0 for r in ok])) if ok else float("nan"),
        "overruns_over_1ms": causes,
    }


def table(rows: list[dict], margin_ms: float) -> str:
    lines = [
        "| clients | requests | 200 / 503 / other | ok/s | round trip p50 / p99 ms "
        "| engine p50 / p99 / max ms | overrun p99 / max ms | iterations (mean) | budget held |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        s = r["statuses"]
        other = sum(v for k, v in s.items() if k not in ("200", "503"))
        other += sum(r["transport_errors"].values())
        held = "yes" if r["overrun_p99_ms"] <= margin_ms else "NO"
        lines.append(
            f"| {r['clients']} | {r['requests']} | {s.get('200', 0)} / {s.get('503', 0)} / {other}"
            f" | {r['ok_per_s']:.1f} | {r['client_p50_ms']:.1f} / {r['client_p99_ms']:.1f} | "
            f"{r['engine_p50_ms']:.1f} / {r['engine_p99_ms']:.1f} / {r['engine_max_ms']:.1f} | "
            f"{r['overrun_p99_ms']:+.1f} / {r['overrun_max_ms']:+.1f} | "
            f"{r['iterations_mean']:.2f} | {held} |"
        )
    return "\n".join(lines)


def main(
    concurrency: str = typer.Option("1,4,16,64", help="Client counts, one row each."),
    duration_s: float = typer.Option(15.0, help="Seconds per row (at most)."),
    max_requests: int = typer.Option(5000, help="Requests per row (at most)."),
    budget_ms: float = typer.Option(50.0, help="budget_ms of every request."),
    points: int = typer.Option(2048, help="Points per cloud."),
    margin_ms: float = typer.Option(10.0, help="Allowed p99 overrun of the budget."),
    threads: int = typer.Option(2, help="ITNET_THREADS of the server."),
    max_concurrent: int = typer.Option(
        0, help="ITNET_LIMITS__MAX_CONCURRENT_REQUESTS (0: the server's default, 2 per core)."
    ),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped or stand-in)."),
    log: Path = typer.Option(Path("/tmp/itnet-load-server.log"), help="Server log file."),
    json_out: Path | None = typer.Option(None, help="Write the rows as JSON here."),
    gc_freeze: bool = typer.Option(True, help="ITNET_GC_FREEZE of the server."),
) -> None:
    """Run the load test and print its table."""
    folder = model_dir(models)
    if max_concurrent <= 0:
        max_concurrent = Settings().limits.max_concurrent_requests  # what the server will use
    env = {"ITNET_THREADS": str(threads), "ITNET_GC_FREEZE": str(gc_freeze).lower(),
           "ITNET_LIMITS__MAX_CONCURRENT_REQUESTS": str(max_concurrent)}  # fmt: skip
    cloud = sample_cloud(points)
    body = json.dumps({"points": cloud.tolist(), "budget_ms": budget_ms}).encode()
    rows = []
    with serve(folder, log, env) as server:
        warm = asyncio.run(closed_loop(server.url, body, 1, 2.0, 20))
        assert warm["rows"] and warm["rows"][0][0] == 200, warm
        rss_before = server.rss_mb()
        for clients in (int(c) for c in concurrency.split(",")):
            result = asyncio.run(closed_loop(server.url, body, clients, duration_s, max_requests))
            rows.append(summarise(result, clients, budget_ms))
            typer.echo(f"{clients} clients: {json.dumps(rows[-1])}", err=True)
        health = httpx.get(f"{server.url}/healthz", timeout=5).status_code
        rss_after = server.rss_mb()
    typer.echo(f"model: {folder / 'chair.onnx'}; cloud {points} points (JSON, "
               f"{len(body):,} bytes); budget {budget_ms:g} ms; server limit {max_concurrent} "
               f"concurrent estimates, {threads} onnxruntime threads, "
               f"gc_freeze {gc_freeze}")  # fmt: skip
    typer.echo(table(rows, margin_ms))
    typer.echo(f"after the run: /healthz {health}; server RSS {rss_before:.0f} -> "
               f"{rss_after:.0f} MiB")  # fmt: skip
    if json_out is not None:
        json_out.write_text(json.dumps({"rows": rows, "budget_ms": budget_ms}, indent=1))


if __name__ == "__main__":
    typer.run(main)
