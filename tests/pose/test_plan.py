"""The pose pipeline's plan: one request, planned once, the same way for every caller."""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar

import numpy as np
import pytest
from pydantic import ValidationError

from itnet.model_card import ModelCard
from itnet.pose import stages
from itnet.pose.catalog import Catalog
from itnet.pose.errors import BadCloudError, BudgetTooSmallError, OverloadedError
from itnet.pose.loop import AnytimeRun
from itnet.pose.plan import fitting_ensemble, plan
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import load_model
from itnet.pose.stages import STAGE_NAMES, Finish


def with_card(model, **fields):
    """The model under a card changed by ``fields`` (same graph, same measured step time)."""
    card = ModelCard.model_validate({**model.card.model_dump(), **fields})
    other = replace(model, card=card)
    other.idle_ms, other.baseline_ms = model.idle_ms, model.baseline_ms
    return other


def test_the_request_is_strict_about_types_and_reads_query_strings():
    for bad in ('{"budget_ms": true}', '{"budget_ms": "50"}', '{"ensemble": 2.0}',
                '{"mirror": 1}', '{"up": "0,1,0"}', '{"speed": 1}'):  # fmt: skip
        with pytest.raises(ValidationError):
            PoseRequest.model_validate_json(bad)
    query = {"budget_ms": "20", "mirror": "false", "up": "0,-1,0", "ensemble": "4"}
    request = PoseRequest.from_query(query)
    assert request == PoseRequest(budget_ms=20, mirror=False, up=[0, -1, 0], ensemble=4)
    assert PoseRequest.from_query(request.to_query()) == request
    with pytest.raises(ValidationError):
        PoseRequest.from_query({"up": "0,x,1"})


def test_the_card_runs_are_kept_where_the_budget_holds_them_whatever_the_load(model):
    card8 = with_card(model, recommended_ensemble=8)
    idle = plan(card8, PoseRequest(budget_ms=10_000))
    assert idle.runs == 8 and idle.fuse
    card8.record_step_ms(1e4, weight=1.0)  # a burst of load: the running step time soars
    assert plan(card8, PoseRequest(budget_ms=10_000)).runs == 8  # the plan does not follow it
    steps = card8.card.recommended_iterations
    tight = 8 * steps * card8.idle_ms * 0.5  # half of what 8 runs' steps take on an idle machine
    assert plan(card8, PoseRequest(budget_ms=tight)).runs == 4
    assert plan(card8, PoseRequest(budget_ms=10_000, ensemble=3)).runs == 3
    assert fitting_ensemble(8, lambda k: k * 10.0, 45.0) == 4
    assert fitting_ensemble(8, lambda k: 0.0, 1.0) == 8


def test_points_per_run_caps_each_runs_points_and_sizes_the_runs_at_them(model, cloud):
    """A request's ``points_per_run``: each run sees at most that many of the cloud, and the
    runs a budget holds are counted at that many points (a step costs about in proportion)."""
    card8 = with_card(model, recommended_ensemble=8)
    steps, points = card8.card.recommended_iterations, card8.card.points
    tight = 8 * steps * card8.run_step_ms(1, points, idle=True) * 0.5  # half of 8 full runs
    assert plan(card8, PoseRequest(budget_ms=tight)).runs == 4
    quarter = plan(card8, PoseRequest(budget_ms=tight, points_per_run=points // 4))
    assert quarter.runs == 8 and quarter.most_points == points // 4
    run = AnytimeRun(quarter, cloud)
    assert run.points.shape[:2] == (8, points // 4)
    with pytest.raises(ValidationError):
        PoseRequest(points_per_run=8)


def test_stages_are_on_by_the_card_and_refused_with_the_stage_reason(model):
    assert plan(model, PoseRequest()).stages == ()  # the tiny card has no mirror, centre, ...
    with pytest.raises(BadCloudError, match="declares no mirror symmetry"):
        plan(model, PoseRequest(mirror=True))
    with pytest.raises(BadCloudError, match="no centre correction"):
        plan(model, PoseRequest(centre=True))
    with pytest.raises(BadCloudError, match="needs ensemble > 1"):
        plan(model, PoseRequest(verify=True, ensemble=1))
    with pytest.raises(BadCloudError, match="no verifier loaded"):
        plan(model, PoseRequest(recheck=True))
    mirrored = with_card(model, mirror_planes=["x"], verify_fused=True, recommended_ensemble=4)
    names = [s.name for s in plan(mirrored, PoseRequest(budget_ms=10_000)).stages]
    assert names == ["verify"]  # fused runs: the mirror only where the card says mirror_fused
    names = [s.name for s in plan(mirrored, PoseRequest(budget_ms=10_000, ensemble=1)).stages]
    assert names == ["mirror"]
    assert plan(mirrored, PoseRequest(ensemble=1, mirror=False)).stages == ()
    assert STAGE_NAMES == ("recheck", "verify", "mirror", "centre")


def test_a_stage_that_does_not_fit_the_budget_left_is_skipped_and_said(model, cloud):
    mirrored = with_card(model, mirror_planes=["x", "z"])
    mirrored.mirror_ms = 1e6  # a plane would take far more than any budget
    run = AnytimeRun(plan(mirrored, PoseRequest(budget_ms=10_000, ensemble=1)), cloud)
    last = run.run_to_end()
    result = run.result()
    assert result["skipped"] == ["mirror"] and result["mirror"] is False
    assert np.allclose(result["T_canonical_from_input"], last.pose)
    assert result["ensemble"] == 1 and result["iterations"] == model.card.recommended_iterations


def test_a_new_stage_is_one_class_and_every_path_gets_it(model, cloud, monkeypatch):
    """A finishing step added to STAGES runs for a pose and inside an alignment alike."""
    from itnet.alignment.estimators import cloud_request, in_process_estimator
    from itnet.alignment.pipeline import AlignOptions, align_clouds

    class HalfTurn:
        name: ClassVar[str] = "half_turn"

        def default(self, model, request, runs):
            return True

        def refusal(self, model, request, runs):
            return None

        def predicted_ms(self, run):
            return 0.0

        def apply(self, run):
            turn = np.diag([-1.0, 1.0, -1.0, 1.0])
            return Finish(turn @ run.last.pose_normalized, {"half_turned": True})

        def not_run(self, run):
            return {"half_turned": False}

    monkeypatch.setattr("itnet.pose.plan.STAGES", (*stages.STAGES, HalfTurn()))
    catalog = Catalog({"tiny": model})
    request = PoseRequest(budget_ms=10_000, model="tiny")
    run = catalog.start(cloud, request)
    run.run_to_end()
    assert run.result()["half_turned"] is True
    estimate = in_process_estimator(catalog, request)
    result = align_clouds(cloud, cloud, estimate, AlignOptions(symmetry="none"))
    assert result.pose_a.result["half_turned"] is True
    alone = catalog.pose(cloud, cloud_request(request))  # the alignment's own pose request
    assert np.allclose(result.pose_a.T_canonical_from_input, alone["T_canonical_from_input"])


def test_no_pose_from_no_step(tiny_model_dir, model, cloud):
    """Under one step: refused at plan time where the idle step says so (422), and a run whose
    budget ran out before its first step is refused (503), never handed the start as a pose."""
    with pytest.raises(BudgetTooSmallError, match="below one step"):
        plan(model, PoseRequest(budget_ms=model.idle_ms / 10))
    cold = load_model(tiny_model_dir / "tiny.onnx", threads=1, warm_up=False)
    run = AnytimeRun(plan(cold, PoseRequest(budget_ms=1e-3)), cloud)
    assert list(run) == [] and run.iteration == 0 and run.stopped_by == "budget"
    with pytest.raises(OverloadedError, match="no step"):
        run.check_served()


def test_a_request_whose_own_arrival_spent_its_budget_is_refused_as_unmeetable(model, cloud):
    """A run whose request took longer to arrive and decode than its budget has room for one
    step: alone on the machine, retrying cannot help (422, naming the binary body); beside other
    runs, the machine was busy (503)."""
    import time

    budget = 5 * model.idle_ms
    late = time.perf_counter() - 3 * budget / 1e3
    run = AnytimeRun(plan(model, PoseRequest(budget_ms=budget)), cloud, late)
    assert run.decode_ms > budget and list(run) == [] and run.iteration == 0
    with pytest.raises(BudgetTooSmallError, match="application/octet-stream"):
        run.check_served(alone=True)
    with pytest.raises(OverloadedError, match="no step"):
        run.check_served(alone=False)
    # Decoding that took most of the budget and left no room for one idle step: the body
    # cannot be posed in time however often it is sent (422); decoding that took little of it
    # while no step fit is a busy moment (a loaded replica), not the body: a retry may succeed.
    squeezed = AnytimeRun(plan(model, PoseRequest(budget_ms=budget)), cloud, late,
                          decode_ms=0.9 * budget)  # fmt: skip
    assert list(squeezed) == []
    with pytest.raises(BudgetTooSmallError, match="application/octet-stream"):
        squeezed.check_served(alone=True)
    busy = AnytimeRun(plan(model, PoseRequest(budget_ms=budget)), cloud, late,
                      decode_ms=0.3 * budget)  # fmt: skip
    assert list(busy) == []
    with pytest.raises(OverloadedError, match="no step"):
        busy.check_served(alone=True)
    catalog = Catalog({"tiny": model})
    late_run = catalog.start(cloud, PoseRequest(budget_ms=budget, model="tiny"), late)
    with (
        pytest.raises(BudgetTooSmallError, match="decoding this request"),
        catalog.serving(late_run),
    ):
        late_run.run_to_end()
    on_time = catalog.start(cloud, PoseRequest(budget_ms=200, model="tiny", max_iterations=2))
    with catalog.serving(on_time):
        on_time.run_to_end()
    assert on_time.iteration == 2


def test_catalog_pose_admits_by_work_and_never_hands_back_a_start(model, tiny_model_dir, cloud):
    """Catalog.pose runs under the catalog's admission: while admitted runs need more work than a
    new run's budget leaves, it is refused (503) before a step; a start with no step is refused
    too (alone, where its own setting up spent the budget: 422); alone, it poses."""
    catalog = Catalog({"tiny": model})
    request = PoseRequest(budget_ms=200, max_iterations=3)
    assert catalog.pose(cloud, request)["iterations"] == 3
    busy = catalog.start(cloud, PoseRequest(budget_ms=10_000, max_iterations=3))
    busy.needed_work_ms = lambda: 1e6  # type: ignore[method-assign]  # work enough for minutes
    with catalog.serving(busy), pytest.raises(OverloadedError, match="busy"):
        catalog.pose(cloud, request)
    assert catalog.admission.running == 0
    assert catalog.pose(cloud, request)["iterations"] == 3  # admitted again once it is done
    cold = load_model(tiny_model_dir / "tiny.onnx", threads=1, warm_up=False)
    # its budget gone before a step, by its own setting up: a retry cannot succeed
    with pytest.raises(BudgetTooSmallError, match="decoding this request"):
        Catalog({"tiny": cold}).pose(cloud, PoseRequest(budget_ms=1e-3))


def test_the_same_request_gives_the_same_pose_every_way(model, cloud):
    catalog = Catalog({"tiny": model})
    request = PoseRequest(budget_ms=10_000, model="tiny", ensemble=4)
    first = catalog.pose(cloud, request)
    again = catalog.start(cloud, request)
    estimates = list(again)
    assert again.result()["T_canonical_from_input"] == first["T_canonical_from_input"]
    assert first["ensemble"] == 4 and len(estimates) == first["iterations"]


class _FixedVerifier:
    """A verifier that likes runs by a fixed score each, and records what it was shown."""

    def __init__(self, scores):
        self.fixed, self.seen = np.asarray(scores, np.float32), []

    def scores(self, points):
        self.seen.append(len(points))
        return self.fixed[: len(points)]

    def predicted_ms(self, runs, points):
        return 0.01


def test_successive_halving_steps_on_only_the_runs_the_verifier_likes_best(model, cloud):
    request = PoseRequest(budget_ms=10_000, ensemble=8, max_iterations=6, verify=False)
    full = plan(model, request)
    halved = replace(full, halving=(2, 3))
    assert (halved.halving_at, halved.halving_keep) == (2, 3)
    assert halved.run_steps(6) == 2 * 8 + 4 * 3 and full.run_steps(6) == 6 * 8
    assert halved.run_steps(6, start=4, now=3) == 2 * 3
    assert replace(full, halving=(2, 8)).halving_at == 0  # keeping every run is no halving

    verifier = _FixedVerifier([0.0, 5.0, -1.0, 4.0, 0.5, 3.0, -2.0, 1.0])
    judged = replace(model, verifier=verifier)
    judged.idle_ms, judged.baseline_ms = model.idle_ms, model.baseline_ms

    def fixed_price(runs: int, points: int, idle: bool = False) -> float:
        """A step's price that the moment's load does not move: the work counts steps."""
        return runs * points / judged.card.points

    judged.run_step_ms = fixed_price  # type: ignore[method-assign]
    run = AnytimeRun(replace(halved, model=judged), cloud)
    drawn = run.points.copy()
    next(run)
    assert run.runs == 8 and verifier.seen == []
    work_before = run.needed_work_ms()
    next(run)  # the second iteration ends with the halving
    assert run.runs == 3 and verifier.seen == [8]
    assert np.array_equal(run.points, drawn[[1, 3, 5]])  # scores 5, 4 and 3
    assert run.needed_work_ms() < work_before
    run.run_to_end()
    assert run.iteration == 6 and run.result()["ensemble"] == 8

    alone = AnytimeRun(halved, cloud)  # no verifier: every run goes on
    alone.run_to_end()
    assert alone.runs == 8


def test_coarse_first_steps_see_a_subset_of_each_runs_points_and_cost_less(model, cloud):
    request = PoseRequest(budget_ms=10_000, ensemble=4, max_iterations=5, verify=False)
    full = plan(model, request)
    coarse = replace(full, coarse=(3, 32))
    size = full.run_points(len(cloud))
    assert [coarse.step_points(i, size) for i in range(5)] == [32, 32, 32, size, size]
    assert coarse.step_points(0, 20) == 20  # never more than a run has

    def per_point(points: int) -> float:
        return float(points)

    assert full.work_ms(5, size, per_point) == 5 * 4 * size
    assert coarse.work_ms(5, size, per_point) == 3 * 4 * 32 + 2 * 4 * size
    assert coarse.work_ms(5, size, per_point, start=4, now=4) == 4 * size
    halved = replace(coarse, halving=(3, 2))  # coarse steps, then the halving's runs on all
    assert halved.work_ms(5, size, per_point) == 3 * 4 * 32 + 2 * 2 * size

    seen: list[tuple[int, int]] = []
    step = model.batched_step

    def recorded(points, poses, latest):
        seen.append(points.shape[:2])
        return step(points, poses, latest)

    watched = replace(model)
    watched.idle_ms, watched.baseline_ms = model.idle_ms, model.baseline_ms
    watched.batched_step = recorded  # type: ignore[method-assign]
    run = AnytimeRun(replace(coarse, model=watched), cloud)
    drawn = run.points.copy()
    run.run_to_end()
    assert seen == [(4, 32)] * 3 + [(4, size)] * 2
    assert run.iteration == 5 and np.array_equal(run.points, drawn)
    assert AnytimeRun(coarse, cloud).run_to_end().pose.shape == (4, 4)

    small = cloud[:100]  # one run sees the whole small cloud: its coarse steps a seeded shuffle
    single = replace(plan(model, request.model_copy(update={"ensemble": 1})), coarse=(2, 32))
    first, second = AnytimeRun(single, small), AnytimeRun(single, small)
    assert np.array_equal(first.points, second.points)
    assert not np.array_equal(first.points[0, :32], AnytimeRun(replace(single, coarse=None),
                                                                small).points[0, :32])  # fmt: skip
