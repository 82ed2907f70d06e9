"""The load test's table puts batching on and off, client mixes and budgets side by side, each
set of rows against its own first row."""

from __future__ import annotations

from benchmarks.load_test import table


def _row(batching: str, clients: int, good: float, overrun: float = 1.0, kind: str = "async",
         budget: float = 20.0) -> dict:  # fmt: skip
    return {"batching": batching, "kind": kind, "budget_ms": budget, "clients": clients, "requests": 10, "statuses": {"200": 9, "503": 1},
            "transport_errors": 0, "ok_per_s": good + 1, "good_per_s": good, "client_p50_ms": 5.0,
            "client_p99_ms": 9.0, "engine_p50_ms": 4.0, "engine_p99_ms": 8.0, "engine_max_ms": 9.0,
            "overrun_p99_ms": overrun, "overrun_max_ms": overrun + 1,
            "wall_minus_budget_p99_ms": 0.5, "iterations_mean": 9.5, "machine_busy_share": 0.9,
            "server_cores": 1.5, "client_cores": 0.4}  # fmt: skip


def test_each_setting_is_shared_against_its_own_first_row() -> None:
    rows = [_row("on", 1, 60.0), _row("on", 16, 90.0), _row("off", 1, 50.0),
            _row("off", 16, 40.0, overrun=12.0)]  # fmt: skip
    lines = [line.split("|") for line in table(rows, margin_ms=10.0).splitlines()[2:]]
    assert [(c[1].strip(), c[4].strip(), c[9].strip()) for c in lines] == [
        ("on", "1", "100%"),
        ("on", "16", "150%"),
        ("off", "1", "100%"),
        ("off", "16", "80%"),
    ]
    assert [c[16].strip() for c in lines] == ["yes", "yes", "yes", "NO"]  # p99 overrun vs margin


def test_each_client_mix_and_budget_is_shared_against_its_own_first_row() -> None:
    rows = [_row("on", 1, 40.0, kind="threads"), _row("on", 16, 20.0, kind="threads"),
            _row("on", 1, 10.0, kind="threads", budget=50.0),
            _row("on", 16, 15.0, kind="threads", budget=50.0),
            _row("on", 1, 50.0), _row("on", 16, 50.0)]  # fmt: skip
    lines = [line.split("|") for line in table(rows, margin_ms=10.0).splitlines()[2:]]
    assert [(c[2].strip(), c[3].strip(), c[4].strip(), c[9].strip()) for c in lines] == [
        ("threads", "20", "1", "100%"),
        ("threads", "20", "16", "50%"),
        ("threads", "50", "1", "100%"),
        ("threads", "50", "16", "150%"),
        ("async", "20", "1", "100%"),
        ("async", "20", "16", "100%"),
    ]
