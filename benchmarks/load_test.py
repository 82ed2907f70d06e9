"""Load test of ``itnet serve`` on loopback: latency, throughput and the budget under concurrency.

    python benchmarks/load_test.py                                  # 1, 4, 16, 64 clients
    python benchmarks/load_test.py --concurrency 1,4,16 --duration-s 20 --budget-ms 50
    python benchmarks/load_test.py --concurrency 1,16,64 --budget-ms 20 --batching on,off
    python benchmarks/load_test.py --clients-kind threads --binary --chair --points 800 \
        --budget-ms 20 --concurrency 1,4,16,64 --retry-s 0.05 --duration-s 8
    python benchmarks/load_test.py --clients-kind async,threads --budget-ms 20,50 --binary \
        --chair --points 800 --retry-s 0.05 --duration-s 8    # both client mixes, one run

Starts a real ``itnet serve`` (uvicorn, the CLI's settings) on a free loopback port, then for
each client count runs that many closed-loop clients (each sends its next request as soon as its
last reply is in) for ``--duration-s`` seconds or ``--max-requests`` requests, whichever comes
first (the rates count the time the row ran). Every request is a JSON cloud of ``--points``
points with ``budget_ms``. The clients run in processes of their own, ``--per-process`` to a
process (one process's event loop driving 64 clients on the server's cores counted its own
queueing as the server's), keep their connections (``--fresh``: a new one per request) and
honour ``Retry-After`` after a 503 (``--retry-s 0.01``: retry after 10 ms instead).
``--clients-kind threads`` runs the clients as plain scripts do instead: a thread each with a
synchronous ``httpx.Client``, all in one process. The machine's busy share and the CPU cores the
server and the clients used are printed with each row.

Per row: replies by status (200, 503 = refused by the concurrency gate), throughput, client
round trip p50/p99, the engine's ``elapsed_ms`` (which starts when the request reaches the app)
p50/p99/max, and the overrun ``elapsed_ms - budget_ms`` at p99 and max. The budget holds when the
p99 overrun is within ``--margin-ms``. ``--batching on,off`` runs every row against a server
that batches the steps of requests in flight into shared calls (the default) and then one that
makes a call a step (``ITNET_BATCH_JOBS=1``), side by side; ``--clients-kind async,threads``
and ``--budget-ms 20,50`` run a set of rows for each client mix and budget against the same
server. Each set's share column is its replies with at least 5 iterations over its first row's;
"first step ends" is when the first step ended after the request arrived (receiving, decoding,
queueing and one step). ``--no-schedule`` asks every request for every step of its runs (the
card's cheaper schedule off), to compare against the default plan.
Prints a markdown table; ``--json-out`` saves the rows.
"""

from __future__ import annotations

import json
from itertools import product
from pathlib import Path

import httpx
import numpy as np
import typer

from benchmarks.harness import (
    ClientPlan,
    CpuMeter,
    model_dir,
    percentile,
    run_clients,
    sample_cloud,
    serve,
)
from itnet.clients.wire import json_request, request_fields
from itnet.pose.request import PoseRequest
from itnet.service.benchmark import GOOD_ITERATIONS
from itnet.service.settings import Settings

JSON = {"content-type": "application/json"}


def chair_cloud(points: int, seed: int = 0) -> np.ndarray:
    """The example chair scan (itnet/examples/chair_a.ply) resampled to ``points`` (float32)."""
    from itnet.cloud_io import read_cloud

    scan = read_cloud(Path(__file__).resolve().parents[1] / "itnet/examples/chair_a.ply")
    rng = np.random.default_rng(seed)
    return scan[rng.choice(len(scan), points, replace=len(scan) < points)].astype(np.float32)


def summarise(result: dict, clients: int, budget_ms: float) -> dict:
    rows = [r for r in result["rows"] if r[0] != 0]
    errors = len(result["rows"]) - len(rows)  # transport errors
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
        "requests": len(result["rows"]),
        "statuses": statuses,
        "transport_errors": errors,
        "client_processes": result["processes"],
        "ok_per_s": len(ok) / result["seconds"],
        # replies that carry a pose of at least GOOD_ITERATIONS steps, a second
        "good_per_s": sum(r[3] >= GOOD_ITERATIONS for r in ok) / result["seconds"],
        "client_p50_ms": percentile(client_ms, 50),
        "client_p99_ms": percentile(client_ms, 99),
        "engine_p50_ms": percentile(engine_ms, 50),
        "engine_p99_ms": percentile(engine_ms, 99),
        "engine_max_ms": float(engine_ms.max()) if len(ok) else float("nan"),
        "wall_minus_budget_p99_ms": percentile(np.array(client_ms) - budget_ms, 99),
        "overrun_p99_ms": percentile(overrun, 99),
        "overrun_max_ms": float(overrun.max()) if len(ok) else float("nan"),
        "iterations_mean": float(np.mean([r[3] for r in ok])) if ok else float("nan"),
        "iterations_median": float(np.median([r[3] for r in ok])) if ok else float("nan"),
        # when the first step ended, ms after the request arrived: what receiving, decoding,
        # queueing and one step took
        "first_step_p50_ms": percentile([r[5] for r in ok if r[3] > 0], 50),
        "zero_iteration_share": float(np.mean([r[3] == 0 for r in ok])) if ok else float("nan"),
        "overruns_over_1ms": causes,
        **result["cpu"],
        "client_cores": result["client_cores"],
    }


def table(rows: list[dict], margin_ms: float) -> str:
    lines = [
        "| batching | clients kind | budget ms | clients | requests | 200 / 503 / other | ok/s "
        "| ≥5 iterations/s | share of the first row's | round trip p50 / p99 ms "
        "| engine p50 / p99 / max ms | overrun p99 / max ms | wall - budget p99 ms "
        "| iterations (mean / median) | first step ends p50 ms | budget held "
        "| CPU busy (machine) / server / clients |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    first: dict[tuple, float] = {}
    for r in rows:
        group = (r["batching"], r["kind"], r["budget_ms"])
        alone = first.setdefault(group, r["good_per_s"])
        share = f"{r['good_per_s'] / alone:.0%}" if alone else "-"
        s = r["statuses"]
        other = sum(v for k, v in s.items() if k not in ("200", "503"))
        other += r["transport_errors"]
        held = "yes" if r["overrun_p99_ms"] <= margin_ms else "NO"
        lines.append(
            f"| {r['batching']} | {r['kind']} | {r['budget_ms']:g} "
            f"| {r['clients']} | {r['requests']} | {s.get('200', 0)} / "
            f"{s.get('503', 0)} / {other} | {r['ok_per_s']:.1f} | {r['good_per_s']:.1f} | {share} | "
            f"{r['client_p50_ms']:.1f} / {r['client_p99_ms']:.1f} | "
            f"{r['engine_p50_ms']:.1f} / {r['engine_p99_ms']:.1f} / {r['engine_max_ms']:.1f} | "
            f"{r['overrun_p99_ms']:+.1f} / {r['overrun_max_ms']:+.1f} | "
            f"{r['wall_minus_budget_p99_ms']:+.1f} | {r['iterations_mean']:.2f} / "
            f"{r.get('iterations_median', float('nan')):.0f} | "
            f"{r.get('first_step_p50_ms', float('nan')):.1f} | {held} | "
            f"{r['machine_busy_share']:.0%} / {r['server_cores']:.2f} / {r['client_cores']:.2f} |"
        )
    return "\n".join(lines)


def main(
    concurrency: str = typer.Option("1,4,16,64", help="Client counts, one row each."),
    duration_s: float = typer.Option(15.0, help="Seconds per row (at most)."),
    max_requests: int = typer.Option(
        100000, help="Requests per row (at most): a guard; the rates count the time the row ran."
    ),
    budget_ms: str = typer.Option(
        "50", help="budget_ms of the requests; several ('20,50'): a set of rows each."
    ),
    points: int = typer.Option(2048, help="Points per cloud."),
    margin_ms: float = typer.Option(10.0, help="Allowed p99 overrun of the budget."),
    threads: int = typer.Option(2, help="ITNET_THREADS of the server."),
    workers: int = typer.Option(1, min=1, help="`itnet serve --workers`: server processes."),
    max_concurrent: int = typer.Option(
        0, help="ITNET_LIMITS__MAX_CONCURRENT_REQUESTS (0: the server's default, 2 per core)."
    ),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped or stand-in)."),
    log: Path = typer.Option(Path("/tmp/itnet-load-server.log"), help="Server log file."),
    json_out: Path | None = typer.Option(None, help="Write the rows as JSON here."),
    gc_freeze: bool = typer.Option(True, help="ITNET_GC_FREEZE of the server."),
    per_process: int = typer.Option(4, help="Clients per client process."),
    retry_s: float = typer.Option(
        -1.0, help="After a 503, wait this long (negative: honour Retry-After)."
    ),
    fresh: bool = typer.Option(False, help="A new connection per request (else keep-alive)."),
    clients_kind: str = typer.Option(
        "async",
        help="'async' (asyncio loops, --per-process to a process) or 'threads' (a thread per "
        "client with a synchronous httpx.Client, all in one process, as plain scripts do); "
        "'async,threads': both, a set of rows each, against the same server.",
    ),
    binary: bool = typer.Option(False, help="float32 bodies (the budget in the query)."),
    chair: bool = typer.Option(
        False, help="the cloud: the example chair scan resampled to --points (else a box)."
    ),
    ensemble: int | None = typer.Option(
        None,
        min=1,
        max=16,
        help="'ensemble' of every request (default: none, the card's plan)",
    ),
    schedule: bool = typer.Option(
        True,
        "--schedule/--no-schedule",
        help="--no-schedule: every request asks for no schedule (every run on all its points "
        "every step: the card's plan without its cheaper steps)",
    ),
    batching: str = typer.Option(
        "on",
        help="'on' (steps of requests in flight share calls), 'off' (ITNET_BATCH_JOBS=1), "
        "or 'on,off': every row against both, a server each.",
    ),
) -> None:
    """Run the load test and print its table."""
    folder = model_dir(models)
    if max_concurrent <= 0:
        max_concurrent = Settings().limits.max_concurrent_requests  # what the server will use
    env = {"ITNET_THREADS": str(threads), "ITNET_GC_FREEZE": str(gc_freeze).lower(),
           "ITNET_LIMITS__MAX_CONCURRENT_REQUESTS": str(max_concurrent)}  # fmt: skip
    kinds = [k.strip() for k in clients_kind.split(",") if k.strip()]
    if not kinds or set(kinds) - {"async", "threads"}:
        raise typer.BadParameter(
            f"--clients-kind: 'async', 'threads' or both, not {clients_kind!r}"
        )
    try:
        budgets = [float(b) for b in budget_ms.split(",") if b.strip()]
    except ValueError:
        budgets = []
    if not budgets or min(budgets) <= 0:
        raise typer.BadParameter(f"--budget-ms: positive numbers, not {budget_ms!r}")
    cloud = chair_cloud(points) if chair else sample_cloud(points)
    rows = []
    settings = [b.strip() for b in batching.split(",") if b.strip()]
    if not settings or set(settings) - {"on", "off"}:
        raise typer.BadParameter(f"--batching: 'on', 'off' or 'on,off', not {batching!r}")
    health, rss = {}, {}
    for setting in settings:
        jobs = {} if setting == "on" else {"ITNET_BATCH_JOBS": "1"}
        with serve(folder, log, {**env, **jobs}, args=["--workers", str(workers)]) as server:
            warm = _bodies(cloud, budgets[0], ensemble, schedule, binary=False)[0]
            for _ in range(20 * workers):  # warm up (each worker)
                assert httpx.post(f"{server.url}/v1/estimate", content=warm, headers=JSON,
                                  timeout=30).status_code == 200  # fmt: skip
            rss_before = server.rss_mb()
            bodies = {budget: _bodies(cloud, budget, ensemble, schedule, binary)
                      for budget in budgets}  # fmt: skip
            counts = [int(c) for c in concurrency.split(",")]
            for kind, budget, clients in product(kinds, budgets, counts):
                sent, content_type, params = bodies[budget]
                threaded = kind == "threads"
                per = clients if threaded else per_process
                procs = -(-clients // per)
                plan = ClientPlan(server.url, sent, content_type, params, fresh=fresh,
                                  retry_s=None if retry_s < 0 else retry_s,
                                  cap=max(1, max_requests // procs), threaded=threaded)  # fmt: skip
                meter = CpuMeter(server.process.pid)
                meter.start()
                result = run_clients(plan, clients, duration_s, per)
                result["cpu"] = meter.stop()
                rows.append({"batching": setting, "kind": kind, "budget_ms": budget,
                             **summarise(result, clients, budget)})  # fmt: skip
                typer.echo(f"{kind} {budget:g} ms {clients} clients: {json.dumps(rows[-1])}",
                           err=True)  # fmt: skip
            health[setting] = httpx.get(f"{server.url}/healthz", timeout=5).status_code
            rss[setting] = f"{rss_before:.0f} -> {server.rss_mb():.0f} MiB"
    sent = _bodies(cloud, budgets[0], ensemble, schedule, binary)[0]
    typer.echo(f"model: {folder / 'chair.onnx'}; cloud {points} points "
               f"({'float32' if binary else 'JSON'}, {len(sent):,} bytes); ensemble {ensemble or 'by the card'}"
               f"{'' if schedule else ', no schedule'}; "
               f"{workers} server process(es), "
               f"each: limit {max_concurrent} concurrent estimates, {threads} onnxruntime threads, "
               f"gc_freeze {gc_freeze}")  # fmt: skip
    typer.echo(table(rows, margin_ms))
    for setting in settings:
        typer.echo(f"batching {setting}, after its rows: /healthz {health[setting]}; server RSS "
                   f"{rss[setting]}")  # fmt: skip
    if json_out is not None:
        json_out.write_text(json.dumps({"rows": rows, "budgets_ms": budgets}, indent=1))


def _bodies(cloud: np.ndarray, budget_ms: float, ensemble: int | None, schedule: bool,
            binary: bool) -> tuple[bytes, str, dict[str, str] | None]:  # fmt: skip
    """A request of ``cloud`` (N, 3) at ``budget_ms``: (body, content type, query parameters):
    JSON with the fields, or float32 with the fields in the query, as the clients send them."""
    request = PoseRequest(budget_ms=budget_ms, ensemble=ensemble,
                          schedule=None if schedule else False)  # fmt: skip
    if binary:
        params = {"budget_ms": str(budget_ms), **request.to_query()}
        return cloud.astype("<f4").tobytes(), "application/octet-stream", params
    body = json_request(cloud, request_fields(request))
    return json.dumps(body).encode(), JSON["content-type"], None


if __name__ == "__main__":
    typer.run(main)
