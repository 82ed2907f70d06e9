"""Schema-based fuzzing of a real ``itnet serve`` over loopback (schemathesis, from /openapi.json).

    python -m benchmarks.fuzz_server --examples 2000

Starts the server with small body limits (so oversize bodies are reached too), sends
``--examples`` schema-valid and schema-violating requests to each operation, and checks every
response: no 5xx, status and body as documented. Afterwards: the server is alive, nothing is in
flight, /metrics counts no 5xx, and its RSS. Prints the statuses seen per operation.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import httpx
import schemathesis
import typer
from hypothesis import HealthCheck, given, settings
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from benchmarks.harness import model_dir, serve

CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance,
          response_schema_conformance]  # fmt: skip


def fuzz(operation: Any, examples: int) -> dict[int, int]:
    statuses: dict[int, int] = {}
    strategy = operation.as_strategy(
        generation_mode=GenerationMode.POSITIVE
    ) | operation.as_strategy(generation_mode=GenerationMode.NEGATIVE)

    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))  # fmt: skip
    @given(case=strategy)
    def call(case: Any) -> None:
        response = case.call(timeout=30)
        statuses[response.status_code] = statuses.get(response.status_code, 0) + 1
        case.validate_response(response, checks=CHECKS)

    call()
    return statuses


def main(
    examples: int = typer.Option(1000, help="Requests per operation (POST /v1/estimate)."),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped or stand-in)."),
    log: Path = typer.Option(Path("/tmp/itnet-fuzz-server.log"), help="Server log file."),
) -> None:
    """Fuzz a live server and print what it answered."""
    env = {"ITNET_LIMITS__MAX_BODY_BYTES": "65536", "ITNET_THREADS": "1"}
    seen: dict[str, dict[int, int]] = {}
    start = time.perf_counter()
    with serve(model_dir(models), log, env) as server:
        schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json")
        for result in schema.get_all_operations():
            operation = result.ok()
            label = f"{operation.method.upper()} {operation.path}"
            seen[label] = fuzz(operation, examples if "estimate" in label else examples // 10)
            typer.echo(f"{label}: {json.dumps(dict(sorted(seen[label].items())))}")
        metrics = httpx.get(f"{server.url}/metrics").text
        health = httpx.get(f"{server.url}/healthz").status_code
        rss = server.rss_mb()
    in_flight = next(line for line in metrics.splitlines() if line.startswith("itnet_in_flight "))
    server_errors = [line for line in metrics.splitlines()
                     if line.startswith("itnet_requests_total") and 'status="5' in line]  # fmt: skip
    total = sum(sum(counts.values()) for counts in seen.values())
    typer.echo(f"{total} requests in {time.perf_counter() - start:.0f} s; /healthz {health}; "
               f"{in_flight}; 5xx counted: {server_errors or 'none'}; server RSS {rss:.0f} MiB")  # fmt: skip


if __name__ == "__main__":
    typer.run(main)
