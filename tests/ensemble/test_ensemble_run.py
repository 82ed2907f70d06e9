"""The ensemble mode of the anytime engine, the CLI and the HTTP API."""

import json

import numpy as np
import pytest
from pydantic import ValidationError

from itnet.fusion import fuse_poses
from itnet.geometry import rotation_angle_deg, viewing_axis_turns
from itnet.pose.runtime import load_model
from tests.pose_runs import run_with


def test_every_estimate_is_the_fused_pose_of_the_runs(model, cloud):
    run = run_with(model, cloud, budget_ms=5000, max_iterations=3, ensemble=4)
    estimates = list(run)
    assert [e.iteration for e in estimates] == [1, 2, 3] and run.stopped_by == "max_iterations"
    assert run.points.shape[0] == 4  # four runs, each on its own subset
    assert not np.allclose(run.points[0], run.points[1])
    fused = fuse_poses(run.poses(), model.card.symmetry)  # input units
    assert np.allclose(estimates[-1].pose, fused, atol=1e-4)
    assert run.result()["ensemble"] == 4


def test_ensemble_runs_start_turned_about_the_viewing_axis(model, cloud):
    run = run_with(model, cloud, budget_ms=5000, max_iterations=1, ensemble=4)
    starts = run.pose_normalized[:, :3, :3]  # before the first step
    assert np.allclose(starts, viewing_axis_turns(4), atol=1e-6)
    assert np.allclose(starts[0], np.eye(3)) and np.allclose(starts[:, :, 2], [0, 0, 1], atol=1e-6)
    assert np.allclose(rotation_angle_deg(starts[1:]), [90.0, 180.0, 90.0], atol=1e-3)


def test_ensemble_of_one_is_the_plain_run(model, cloud):
    plain = run_with(model, cloud, budget_ms=5000, max_iterations=3).run_to_end()
    one = run_with(model, cloud, budget_ms=5000, max_iterations=3, ensemble=1).run_to_end()
    assert np.array_equal(plain.pose, one.pose)


def test_small_clouds_still_get_different_subsets(model, rng):
    small = rng.normal(size=(100, 3))
    run = run_with(model, small, budget_ms=5000, max_iterations=1, ensemble=3)
    assert run.points.shape == (3, 80, 3)
    assert not np.allclose(run.points[0], run.points[2])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"ensemble": 0}, "greater than or equal to 1"),
        ({"ensemble": 17}, "less than or equal to 16"),
    ],
)
def test_bad_ensemble_requests_are_refused(model, cloud, kwargs, message):
    with pytest.raises(ValidationError, match=message):
        run_with(model, cloud, **kwargs)


@pytest.mark.timing
def test_ensemble_stops_within_its_budget(model, cloud):
    run = run_with(model, cloud, budget_ms=30, max_iterations=200, ensemble=8)
    run.run_to_end()
    assert run.stopped_by in ("budget", "converged") and run.elapsed_ms() < 30 + 10


def test_http_and_cli_accept_ensemble(tiny_model_dir, tmp_path, cloud):
    from fastapi.testclient import TestClient
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    settings = Settings(model_dir=tiny_model_dir)
    with TestClient(create_app(settings)) as client:
        body = {"points": cloud.tolist(), "model": "tiny", "max_iterations": 2, "budget_ms": 5000}
        reply = client.post("/v1/estimate", json={**body, "ensemble": 4})
        assert reply.status_code == 200, reply.text
        assert reply.json()["ensemble"] == 4 and reply.json()["iterations"] == 2
        for bad in (0, 17, "many"):
            refused = client.post("/v1/estimate", json={**body, "ensemble": bad})
            assert refused.status_code == 422 and "ensemble" in refused.text
        assert client.post("/v1/estimate", json=body).json()["ensemble"] == 1
    path = tmp_path / "cloud.npy"
    np.save(path, cloud.astype(np.float32))
    args = ["pose", str(path), "--model", "tiny", "--model-dir", str(tiny_model_dir), "--json"]
    out = CliRunner().invoke(app, [*args, "--ensemble", "3", "--max-iterations", "2"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output.strip().splitlines()[-1])["ensemble"] == 3


@pytest.fixture(scope="module")
def fused_model_dir(tmp_path_factory):
    """A folder with 'tiny4', whose card recommends 4 runs fused, and plain 'tiny'."""
    from itnet.export.onnx_export import export_step
    from itnet.model_card import ModelCard
    from tests.conftest import make_tiny_net

    folder = tmp_path_factory.mktemp("fused")
    net = make_tiny_net()
    export_step(net, ModelCard(name="tiny", category="chair", points=256), folder / "tiny.onnx")
    card = ModelCard(name="tiny4", category="bed", points=256, recommended_ensemble=4)
    export_step(net, card, folder / "tiny4.onnx")
    return folder


def test_a_card_recommending_an_ensemble_runs_it_unless_the_request_says(fused_model_dir, cloud):
    """The card's recommended_ensemble is the default of the pipeline, the HTTP API, the stream
    and the CLI; a request's own ensemble (1 included) wins."""
    from fastapi.testclient import TestClient
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    fused = load_model(fused_model_dir / "tiny4.onnx", warm_up=False)
    assert run_with(fused, cloud, budget_ms=5000, max_iterations=2).plan.runs == 4
    assert run_with(fused, cloud, budget_ms=5000, max_iterations=2, ensemble=1).plan.runs == 1

    with TestClient(create_app(Settings(model_dir=fused_model_dir))) as client:
        listed = {m["name"]: m for m in client.get("/v1/models").json()["models"]}
        assert listed["tiny4"]["recommended_ensemble"] == 4
        assert listed["tiny"]["recommended_ensemble"] == 1
        body = {"points": cloud.tolist(), "max_iterations": 2, "budget_ms": 5000}
        assert client.post("/v1/estimate", json={**body, "model": "tiny4"}).json()["ensemble"] == 4
        one = client.post("/v1/estimate", json={**body, "model": "tiny4", "ensemble": 1}).json()
        assert one["ensemble"] == 1 and one["iterations"] == 2
        assert client.post("/v1/estimate", json={**body, "model": "tiny"}).json()["ensemble"] == 1
        with client.websocket_connect("/v1/estimate/stream") as ws:
            ws.send_json({**body, "model": "tiny4"})
            messages = [ws.receive_json() for _ in range(3)]
        assert [m["type"] for m in messages] == ["estimate", "estimate", "result"]
        assert messages[-1]["ensemble"] == 4
    path = fused_model_dir / "cloud.npy"
    np.save(path, cloud.astype(np.float32))
    args = ["pose", str(path), "--model", "tiny4", "--model-dir", str(fused_model_dir), "--json"]
    out = CliRunner().invoke(app, [*args, "--max-iterations", "2"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output.strip().splitlines()[-1])["ensemble"] == 4
    out = CliRunner().invoke(app, [*args, "--max-iterations", "2", "--ensemble", "1"])
    assert json.loads(out.output.strip().splitlines()[-1])["ensemble"] == 1


@pytest.mark.parametrize(
    ("recommended", "step_ms", "iterations", "available_ms", "runs"),
    [
        (8, 0.5, 10, 50.0, 8),  # 8 runs x 10 steps x 0.5 ms = 40 ms: fits
        (8, 0.5, 10, 30.0, 4),  # 40 ms does not; 4 runs (20 ms) do
        (8, 0.5, 10, 12.0, 2),
        (8, 0.5, 10, 4.0, 1),  # not even one run fits: one run, the budget stops it
        (4, 0.5, 10, 1000.0, 4),  # never more than the card's
        (8, 0.0, 10, 1.0, 8),  # no timing yet: the card's
        (1, 5.0, 10, 1.0, 1),
    ],
)
def test_the_default_ensemble_is_what_the_budget_holds(
    recommended, step_ms, iterations, available_ms, runs
):
    from itnet.pose.plan import fitting_ensemble

    work = lambda k: k * step_ms * iterations  # noqa: E731 (every run, every iteration)
    assert fitting_ensemble(recommended, work, available_ms) == runs


def test_a_tight_budget_gets_fewer_default_runs_and_an_explicit_ensemble_is_kept(
    fused_model_dir, cloud
):
    """A run's step measured at 1 ms on an idle machine: 4 runs x 10 iterations need 40 ms. A
    25 ms request that names no ensemble gets 2 runs (20 ms), a 9 ms one a single run; a request
    that names 4 gets 4, whatever the budget."""
    fused = load_model(fused_model_dir / "tiny4.onnx", warm_up=False)
    fused.idle_ms = 1.0
    assert run_with(fused, cloud, budget_ms=100, max_iterations=10).plan.runs == 4
    assert run_with(fused, cloud, budget_ms=25, max_iterations=10).plan.runs == 2
    assert run_with(fused, cloud, budget_ms=9, max_iterations=10).plan.runs == 1
    assert run_with(fused, cloud, budget_ms=25, max_iterations=5).plan.runs == 4  # 20 ms
    assert run_with(fused, cloud, budget_ms=9, max_iterations=10, ensemble=4).plan.runs == 4
    # the reply says how many ran
    run = run_with(fused, cloud, budget_ms=25, max_iterations=10)
    assert run.run_to_end() is not None and run.result()["ensemble"] == 2


def test_the_service_plans_the_same_runs_whatever_is_in_flight(fused_model_dir, cloud):
    """The plan follows the card, the request and the idle step time, not the load: twelve
    estimates in flight and a step time inflated by them change nothing."""
    from itnet.pose.request import PoseRequest
    from itnet.service.metrics import Metrics
    from itnet.service.settings import Settings
    from itnet.service.state import ServiceState

    state = ServiceState(Settings(model_dir=fused_model_dir, warm_up=False), Metrics())
    state.load()
    model = state.models["tiny4"]
    model.idle_ms, model.concurrent_steps = 1.0, 1
    params = PoseRequest(model="tiny4", budget_ms=100, max_iterations=10)
    assert state.start_run(cloud, params).plan.runs == 4  # nothing else in flight
    state.gate.active = 12
    model.record_step_ms(50.0, weight=1.0)
    assert state.start_run(cloud, params).plan.runs == 4


def test_alignment_through_the_service_weighs_the_same_poses_as_in_process(fused_model_dir, cloud):
    """itnet-align --server (POST /v1/align) and in-process run the same request through the
    same pipeline: the same poses of 4 fused runs each (tiny4's card recommends 4, plain tiny's
    one: an alignment asks for 4 of either), the same answer."""
    from fastapi.testclient import TestClient

    from itnet.alignment import align
    from itnet.alignment.request import AlignRequest
    from itnet.clients import ItnetClient
    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    other = cloud[::-1] @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]) + [0.3, 0, 0]
    with TestClient(create_app(Settings(model_dir=fused_model_dir, warm_up=False))) as served:
        http = ItnetClient("http://testserver")
        http._http = served  # the app in-process: TestClient is an httpx.Client
        catalog = served.app.state.service.catalog  # type: ignore[attr-defined]
        for name in ("tiny4", "tiny"):
            request = AlignRequest(model=name, budget_ms=5000, max_iterations=3, refine=False)
            remote = http.align(cloud, other, request)
            local = align(catalog, cloud, other, request)
            assert len(local.pose_a.runs) == len(local.pose_b.runs) == 4
            assert remote["T_canonical_from_a"]["ensemble"] == 4
            assert remote["hypothesis"] == local.hypotheses[local.chosen].source
            assert np.allclose(remote["T_b_from_a"], local.T_b_from_a, atol=1e-6)
            pose_a = remote["T_canonical_from_a"]["T_canonical_from_input"]
            assert np.allclose(pose_a, local.pose_a.T_canonical_from_input, atol=1e-6)


def test_a_plans_points_cap_what_each_run_sees(model, cloud):
    """A plan with ``points`` gives every run at most that many of the cloud (single and fused
    runs alike), each fused run its own subset; without it, the card's count."""
    from dataclasses import replace

    from itnet.pose.loop import AnytimeRun
    from itnet.pose.plan import plan
    from itnet.pose.request import PoseRequest

    cloud = np.asarray(cloud)
    assert len(cloud) > model.card.points
    for ensemble in (1, 4):
        planned = plan(model, PoseRequest(budget_ms=5000, max_iterations=2, ensemble=ensemble))
        assert AnytimeRun(planned, cloud).points.shape[1] == model.card.points
        run = AnytimeRun(replace(planned, points=64), cloud)
        assert run.points.shape == (ensemble, 64, 3)
        assert [e.iteration for e in run] == [1, 2]
    assert not np.allclose(run.points[0], run.points[1])
