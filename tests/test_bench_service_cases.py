"""The accuracy-mode cases of benchmarks/bench_service.py."""

from __future__ import annotations

import pytest

from benchmarks.bench_service import parse_cases


def test_cases_parse_models_budgets_and_runs() -> None:
    assert parse_cases("chair:50:8,bathtub:20:default") == [
        ("chair", 50.0, 8),
        ("bathtub", 20.0, None),
    ]
    assert parse_cases("") == []


def test_a_malformed_case_is_refused() -> None:
    with pytest.raises(ValueError):
        parse_cases("chair:50")
