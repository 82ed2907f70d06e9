"""Admission by what the machine delivers (``itnet.pose.admission.DeliveryLimit``): starved runs
lower the runs admitted at once, runs served in full raise it again, and the service's gate
refuses beyond it before reading a body."""

from __future__ import annotations

import math

import numpy as np
import pytest

from itnet.pose.admission import DECREASE, DELIVERED_SHARE, Admission, DeliveryLimit
from itnet.pose.catalog import Catalog
from itnet.pose.errors import OverloadedError
from itnet.pose.request import PoseRequest


def test_starved_runs_cut_the_limit_once_a_moment_and_full_ones_raise_it_again() -> None:
    limit = DeliveryLimit(ceiling=16)
    assert limit.allowed() == 16
    limit.record(10, 10, window_s=0.05, now=1.0)  # served in full: stays at the ceiling
    assert limit.value == 16
    limit.record(3, 10, window_s=0.05, now=1.0)  # starved: cut
    assert limit.value == pytest.approx(16 * DECREASE)
    limit.record(2, 10, window_s=0.05, now=1.01)  # the same overloaded moment: not cut again
    assert limit.value == pytest.approx(16 * DECREASE)
    for k in range(40):  # a long overload: down to one run at a time, never below
        limit.record(0, 10, window_s=0.05, now=2.0 + k)
    assert limit.allowed() == 1 and limit.value == 1.0
    served = math.ceil(DELIVERED_SHARE * 10)
    limit.record(served - 1, 10, window_s=0.05, now=49.0)  # short of its idle iterations: cut
    assert limit.value == 1.0
    limit.record(served, 10, window_s=0.05, now=50.0)  # enough of them: served in full
    assert limit.value == pytest.approx(2.0)
    for _ in range(200):
        limit.record(10, 10, window_s=0.05)
    assert limit.allowed() == 16  # recovered, up to the ceiling
    limit.record(5, 0, window_s=0.05)  # nothing expected: says nothing
    assert limit.allowed() == 16


def test_the_admission_admits_no_more_runs_than_are_now_served_in_full(model, cloud) -> None:
    catalog = Catalog({"tiny": model}, admission=Admission(ceiling=4))
    request = PoseRequest(budget_ms=10_000, max_iterations=3)
    first = catalog.start(cloud, request)
    catalog.admission.delivery.value = 1.0  # the machine served only one at a time lately
    with catalog.serving(first):
        with pytest.raises(OverloadedError, match="1 at once in full"):
            catalog.pose(cloud, request)
        catalog.admission.delivery.value = 2.0
        second = catalog.start(cloud, request)
        with catalog.serving(second):  # room for two now
            second.run_to_end()
        first.run_to_end()
    # both got the iterations they asked for: the limit rises
    assert catalog.admission.delivery.value > 2.0
    alone = catalog.start(cloud, request)
    catalog.admission.delivery.value = 1.0
    with catalog.serving(alone):  # a run alone is always admitted
        alone.run_to_end()
    assert alone.iteration == 3


def test_a_run_its_budget_stopped_early_counts_against_its_idle_iterations(model, cloud) -> None:
    catalog = Catalog({"tiny": model}, admission=Admission(ceiling=8))
    run = catalog.start(cloud, PoseRequest(budget_ms=10_000, max_iterations=4))
    assert run.idle_iterations() == 4  # the budget gives every asked-for iteration when idle
    with catalog.serving(run):
        for _ in range(2):
            next(run)
        run.stopped_by = "budget"  # as a loaded machine stops it: 2 of 4
    assert catalog.admission.delivery.value == pytest.approx(8 * DECREASE)
    cancelled = catalog.start(cloud, PoseRequest(budget_ms=10_000, max_iterations=4))
    with catalog.serving(cancelled):
        next(cancelled)
        cancelled.cancel()
        cancelled.run_to_end()
    assert catalog.admission.delivery.value == pytest.approx(8 * DECREASE)  # says nothing


def test_the_service_gate_refuses_beyond_what_is_served_in_full_before_the_body(tiny_model_dir):
    from fastapi.testclient import TestClient

    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    body = {"points": np.random.default_rng(1).normal(size=(64, 3)).tolist(), "budget_ms": 200}
    with TestClient(create_app(Settings(model_dir=tiny_model_dir, warm_up=False))) as client:
        state = client.app.state.service  # type: ignore[attr-defined]
        assert state.gate.current_limit() == state.gate.limit
        assert client.post("/v1/estimate", json=body).status_code == 200
        state.admission.delivery.value = 1.0  # lately one estimate at a time was served in full
        state.gate.active = 1  # one in flight
        refused = client.post("/v1/estimate", json=body)
        assert refused.status_code == 503 and "1 served in full now" in refused.text
        assert refused.headers["Retry-After"]
        state.gate.active = 0  # alone: served, and served in full it raises the limit
        assert client.post("/v1/estimate", json=body).status_code == 200
        assert state.admission.delivery.value == pytest.approx(2.0)


def test_the_service_sets_the_interpreters_switch_interval_at_start_up(tiny_model_dir):
    import sys

    from fastapi.testclient import TestClient

    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    before = sys.getswitchinterval()
    try:
        settings = Settings(model_dir=tiny_model_dir, warm_up=False, switch_interval_ms=2.0)
        with TestClient(create_app(settings)):
            assert sys.getswitchinterval() == pytest.approx(0.002)
    finally:
        sys.setswitchinterval(before)
