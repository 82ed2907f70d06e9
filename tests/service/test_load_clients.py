"""The load benchmark's clients: a row that reaches its request cap before its duration counts
its rates over the time it ran, not over the duration asked for."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from benchmarks.harness import ClientPlan, run_clients


class _Busy(BaseHTTPRequestHandler):
    """Refuses every estimate at once, as a full server does."""

    def do_POST(self) -> None:  # the http.server name
        self.rfile.read(int(self.headers.get("content-length", 0)))
        body = b'{"detail": "busy", "kind": "overloaded"}'
        self.send_response(503)
        self.send_header("content-type", "application/json")
        self.send_header("retry-after", "1")
        self.send_header("content-length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def busy_url() -> Iterator[str]:
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Busy)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize("threaded", [True, False])
def test_a_row_cut_by_its_cap_counts_the_time_it_ran(busy_url: str, threaded: bool) -> None:
    plan = ClientPlan(busy_url, b"{}", retry_s=0.0, cap=40, threaded=threaded)
    result = run_clients(plan, clients=2, seconds=30.0, per_process=2)
    assert 40 <= len(result["rows"]) <= 41  # the cap, and the one the other client sent
    assert {row[0] for row in result["rows"]} == {503}
    assert result["seconds"] < 10.0  # the cap ended the row long before its 30 s


def test_a_row_that_runs_its_duration_counts_the_duration(busy_url: str) -> None:
    plan = ClientPlan(busy_url, b"{}", retry_s=0.05, threaded=True)
    result = run_clients(plan, clients=1, seconds=1.0, per_process=1)
    assert result["seconds"] == 1.0 and 5 <= len(result["rows"]) <= 25
