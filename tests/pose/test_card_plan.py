"""A card's plan: coarse first steps and successive halving, set with their measurement and
served by every request that model answers."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.cli import app
from itnet.measurements import Measurement
from itnet.model_card import ModelCard
from itnet.pose.loop import AnytimeRun
from itnet.pose.plan import plan
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import load_model


def _report(accuracy: float, paired: bool, runs: int = 8, point_steps: float = 20480.0) -> dict:
    """A ``benchmarks.bench_ensemble`` JSON of ``runs`` runs on 40 paper views, each pose
    stepping ``point_steps`` points in all."""
    row = {"accuracy": accuracy, "scans": 40, "median_elapsed_ms": 20.0,
           "mean_point_steps": point_steps}  # fmt: skip
    if paired:
        row["versus_baseline"] = {"accuracy": accuracy, "gain": -0.5, "gain_stderr": 1.0}
    return {"machine": "test", "budget_ms": 1000.0, "split": "val", "paper": {str(runs): row}}


def test_the_card_command_sets_the_plan_only_with_its_measurement(tiny_model_dir, tmp_path):
    source, out = str(tiny_model_dir / "tiny.onnx"), tmp_path / "planned.onnx"
    bare = CliRunner().invoke(app, ["card", source, "--coarse-steps", "4,64", "--out", str(out)])
    assert bare.exit_code == 2 and "--with-plan" in bare.output and not out.exists()
    (tmp_path / "full.json").write_text(json.dumps(_report(80.0, paired=False)))
    (tmp_path / "plan.json").write_text(json.dumps(_report(79.5, True, point_steps=6144.0)))
    measured = ["--without-plan", str(tmp_path / "full.json"),
                "--with-plan", str(tmp_path / "plan.json")]  # fmt: skip
    for bad in ("4", "4,0", "a,b", "4,64,2"):
        refused = CliRunner().invoke(app, ["card", source, "--coarse-steps", bad, *measured])
        assert refused.exit_code == 2 and "two positive integers" in refused.output
    done = CliRunner().invoke(app, ["card", source, "--coarse-steps", "4,64", "--halving", "4,3",
                                    *measured, "--out", str(out)])  # fmt: skip
    assert done.exit_code == 0, done.output
    card = load_model(out, warm_up=False).card
    assert (card.coarse_steps, card.halving) == ((4, 64), (4, 3))
    # the schedule's share of the network's work: points stepped, against every step's
    assert "paper 8 runs 80.0% -> 79.5% (-0.5 ± 1.0, 40 scans, 30% of the work)" in (
        card.plan_evaluation
    )
    measurement = Measurement.parse("plan", card.plan_evaluation)
    assert measurement.text() == card.plan_evaluation and measurement.result("paper").runs == 8
    assert [m.kind for m in card.measurements] == ["plan"]
    # measured once, the schedule can be switched off and on again without a report
    off = CliRunner().invoke(app, ["card", str(out), "--coarse-steps", "none"])
    assert off.exit_code == 0, off.output
    assert load_model(out, warm_up=False).card.coarse_steps is None
    assert load_model(tiny_model_dir / "tiny.onnx", warm_up=False).card.coarse_steps is None
    # a card that runs one run measures its schedule on that run
    (tmp_path / "one.json").write_text(json.dumps(_report(70.0, False, runs=1)))
    (tmp_path / "one_plan.json").write_text(json.dumps(_report(70.5, True, 1, 8192.0)))
    one = CliRunner().invoke(app, ["card", source, "--coarse-steps", "9,64", "--without-plan",
                                   str(tmp_path / "one.json"), "--with-plan",
                                   str(tmp_path / "one_plan.json"), "--out", str(out)])  # fmt: skip
    assert one.exit_code == 0, one.output
    line = load_model(out, warm_up=False).card.plan_evaluation
    assert line.startswith("one run within 1000 ms") and "40 scans, 40% of the work)" in line
    assert Measurement.parse("plan", line).result("paper").runs == 1


@pytest.mark.parametrize("ensemble", [None, 8])
def test_fused_runs_take_the_cards_schedule_and_fewer_runs_only_where_it_does_not_fit(
    model, ensemble
):
    card = ModelCard.model_validate({**model.card.model_dump(), "coarse_steps": (3, 32),
                                     "halving": (3, 2), "recommended_ensemble": 8})  # fmt: skip
    scheduled = replace(model, card=card)
    scheduled.idle_ms, scheduled.baseline_ms = model.idle_ms, model.baseline_ms
    plain = replace(scheduled, card=card.model_copy(update={"coarse_steps": None,
                                                            "halving": None}))  # fmt: skip
    plain.idle_ms, plain.baseline_ms = model.idle_ms, model.baseline_ms
    every_step = 8 * model.run_step_ms(1, card.points, idle=True) * card.recommended_iterations

    def planned(which, budget_ms, **fields):
        request = PoseRequest(budget_ms=budget_ms, ensemble=ensemble, verify=False, **fields)
        return plan(which, request)

    roomy = planned(scheduled, 10 * every_step)  # every step would fit: the schedule all the same
    assert (roomy.coarse, roomy.halving, roomy.runs) == ((3, 32), (3, 2), 8)
    assert planned(scheduled, 10 * every_step, schedule=False).coarse is None
    tight = planned(scheduled, 0.8 * every_step)  # every step does not: the schedule, 8 runs
    assert (tight.coarse, tight.halving, tight.runs) == ((3, 32), (3, 2), 8)
    # the schedule's work: 8 runs x 3 steps x 32 points, then 2 runs x 7 steps x all points
    assert tight.work_ms(10, card.points, lambda n: n) == 8 * 3 * 32 + 2 * 7 * card.points
    # without a schedule the same budget gets half the runs (a request naming 8 keeps 8, and
    # its steps stop by the budget); a request that asks for no schedule gets none, and fewer
    # runs where it names none, as the plain card does
    assert planned(plain, 0.8 * every_step).runs == (4 if ensemble is None else 8)
    unscheduled = planned(scheduled, 0.8 * every_step, schedule=False)
    assert (unscheduled.coarse, unscheduled.halving) == (None, None)
    assert unscheduled.runs == planned(plain, 0.8 * every_step).runs
    # measured on fused runs: a single run takes every step, however tight; a card that fuses
    # no runs measured its schedule on its single run, and serves it
    single = plan(scheduled, PoseRequest(budget_ms=0.05 * every_step, ensemble=1))
    assert (single.coarse, single.halving) == (None, None)
    one = replace(scheduled, card=card.model_copy(update={"recommended_ensemble": 1}))
    one.idle_ms, one.baseline_ms = model.idle_ms, model.baseline_ms
    assert plan(one, PoseRequest(budget_ms=10 * every_step)).coarse == (3, 32)

    cloud = np.random.default_rng(2).normal(size=(500, 3))
    run = AnytimeRun(replace(tight, budget_ms=10_000.0), cloud)  # the schedule's steps, in full
    run.run_to_end()  # no verifier beside the tiny model: every run goes on
    assert run.iteration == card.recommended_iterations and run.result()["ensemble"] == 8
    # the network's work it did: 3 steps of 8 runs on 32 points, then the rest on all 256
    assert run.point_steps == 8 * 3 * 32 + 8 * (card.recommended_iterations - 3) * 256


def test_the_models_table_says_each_models_plan():
    from itnet.model_listing import LEGEND, runs_cell

    assert runs_cell(8, (4, 64), (4, 3)) == "8, 4x64 pts, 3 kept"
    assert runs_cell(1, (9, 64), (4, 3)) == "1, 9x64 pts"  # one run: nothing to keep
    assert runs_cell(8, None, None) == "8"
    assert "pts" in LEGEND and "kept" in LEGEND
