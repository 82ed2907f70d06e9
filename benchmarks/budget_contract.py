"""The budget as a contract: how late default requests end, warm and the first after a start.

    python -m benchmarks.budget_contract                       # budgets 5, 10, 20, 50 ms
    python -m benchmarks.budget_contract --budgets 20 --requests 500

For each budget: a fresh ``itnet serve`` (loopback, a free port, the shipped models), its first
request timed apart, then ``--requests`` more one after another. Every request is a default
chair request (a 2,048-point cloud in metres, binary float32 body, no options but the budget).
Lateness is the service's own ``elapsed_ms`` (from the request's arrival to the reply leaving
the handler) minus ``budget_ms``. A reply that carries no pose is not a 200: refusals (422 for a
budget under one step, 503 for a busy machine) are counted apart, and a 200 with 0 iterations
would be a failure of the contract. Prints a markdown table; ``--json-out`` saves it.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import httpx
import numpy as np
import typer

from benchmarks.harness import model_dir, sample_cloud, serve

BINARY = {"content-type": "application/octet-stream"}


def post(http: httpx.Client, body: bytes, budget_ms: float) -> tuple[int, float, int]:
    """(status, elapsed_ms - budget_ms (nan for a refusal), iterations (-1 for a refusal))."""
    reply = http.post("/v1/estimate", content=body, headers=BINARY,
                      params={"budget_ms": budget_ms})  # fmt: skip
    if reply.status_code != 200:
        return reply.status_code, float("nan"), -1
    data = reply.json()
    return 200, float(data["elapsed_ms"]) - budget_ms, int(data["iterations"])


def measure(budget_ms: float, requests: int, folder: Path, log: Path) -> dict:
    body = np.ascontiguousarray(sample_cloud(2048, seed=3), dtype="<f4").tobytes()
    with serve(folder, log) as server, httpx.Client(base_url=server.url, timeout=30) as http:
        first = post(http, body, budget_ms)
        rows = [post(http, body, budget_ms) for _ in range(requests)]
    served = [r for r in rows if r[0] == 200]
    late = np.array([r[1] for r in served])
    statuses = sorted({r[0] for r in rows} - {200})
    refused = {str(s): sum(r[0] == s for r in rows) for s in statuses}
    return {
        "budget_ms": budget_ms,
        "first": {"status": first[0], "late_ms": round(first[1], 2), "iterations": first[2]},
        "requests": len(rows),
        "refused": refused,
        "zero_iteration_200s": sum(r[2] == 0 for r in served),
        "over_1ms_share": float(np.mean(late > 1.0)) if len(late) else float("nan"),
        "over_3ms": int(np.sum(late > 3.0)),
        "late_p99_ms": float(np.percentile(late, 99)) if len(late) else float("nan"),
        "late_max_ms": float(late.max()) if len(late) else float("nan"),
        "iterations_median": float(np.median([r[2] for r in served])) if served else 0.0,
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| budget ms | first after start: late ms, iterations | requests | refused | 200s of 0 "
        "iterations | > 1 ms late | > 3 ms late | late p99 / max ms | iterations (median) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        first = r["first"]
        lines.append(
            f"| {r['budget_ms']:g} | {first['late_ms']:+.2f}, {first['iterations']} | "
            f"{r['requests']} | {r['refused'] or 0} | {r['zero_iteration_200s']} | "
            f"{r['over_1ms_share']:.1%} | {r['over_3ms']} | {r['late_p99_ms']:+.2f} / "
            f"{r['late_max_ms']:+.2f} | {r['iterations_median']:g} |"
        )
    return "\n".join(lines)


def main(
    budgets: str = typer.Option("5,10,20,50", help="Budgets, ms, a fresh server each."),
    requests: int = typer.Option(300, min=1, help="Warm requests per budget."),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped)."),
    log: Path = typer.Option(Path("/tmp/itnet-budget-server.log"), help="Server log file."),
    json_out: Path | None = typer.Option(None, help="Write the rows as JSON here."),
) -> None:
    """Run the measurement and print its table."""
    folder = model_dir(models)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f} at the start")  # fmt: skip
    rows = [measure(float(b), requests, folder, log) for b in budgets.split(",")]
    print(table(rows))
    if json_out is not None:
        json_out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    typer.run(main)
