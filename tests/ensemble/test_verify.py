"""verify: fused runs anchored by the run that sits most firmly in its basin (itnet.basin), in
the engine, the HTTP API, the stream, the CLI and the card."""

import json
from dataclasses import replace

import numpy as np
import pytest

from itnet.basin import PROBE_DEG, PROBE_STEPS, basin_drift, firm_anchor, probe_turns
from itnet.fusion import fuse_poses, medoid_index
from itnet.pose.errors import BadCloudError
from itnet.pose.loop import AnytimeRun
from itnet.pose.runtime import load_model
from itnet.preprocess import pose_from_normalized
from tests.pose_runs import run_with


def _anchored(model, run: AnytimeRun) -> np.ndarray:
    """What verify should answer for a finished run, computed here from its runs' poses."""
    drift = basin_drift(
        lambda x, pose: model.step(x, pose)[0],
        run.points,
        run.pose_normalized,
        probe_turns(PROBE_DEG),
        PROBE_STEPS,
    )
    anchor = firm_anchor(drift, medoid_index(run.pose_normalized, model.card.symmetry))
    anchored = fuse_poses(run.pose_normalized, model.card.symmetry, anchor=anchor)
    return pose_from_normalized(anchored, run.normalization)


def test_a_verified_run_answers_the_fusion_anchored_by_its_firmest_run(model, cloud):
    run = run_with(model, cloud, budget_ms=5000, max_iterations=3, ensemble=4, verify=True)
    estimates = list(run)
    assert [e.iteration for e in estimates] == [1, 2, 3]  # the stream is the fused pose's
    assert np.allclose(estimates[-1].pose, fuse_poses(run.poses(), model.card.symmetry), atol=1e-4)
    assert run.result()["verified"] is True and run.result()["iterations"] == 3
    assert np.allclose(run.last.pose, _anchored(model, run), atol=1e-4)


def test_a_budget_that_cannot_hold_the_probes_keeps_the_plain_fusion(model, cloud):
    run = run_with(model, cloud, budget_ms=5000, max_iterations=3, ensemble=4, verify=True)
    fused = [next(run) for _ in range(3)][-1]
    run.plan = replace(run.plan, budget_ms=run.elapsed_ms() + 0.01)  # no time for the probes
    assert run.run_to_end() is fused or np.allclose(run.last.pose, fused.pose)
    assert run.result()["verified"] is False and run.result()["skipped"] == ["verify"]


def test_a_cancelled_run_is_not_verified(model, cloud):
    run = run_with(model, cloud, budget_ms=5000, max_iterations=3, ensemble=4, verify=True)
    next(run)
    run.cancel()
    run.run_to_end()
    assert run.stopped_by == "cancelled" and run.result()["verified"] is False


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"verify": True}, "needs ensemble > 1"),
        ({"verify": True, "ensemble": 1}, "needs ensemble > 1"),
        (
            {"verify": True, "ensemble": 4, "up": [0.0, 1.0, 0.0]},
            "verify with up needs the category.s learned verifier",
        ),
    ],
)
def test_verify_without_fused_runs_or_with_up_is_refused(model, cloud, kwargs, message):
    with pytest.raises(BadCloudError, match=message):
        run_with(model, cloud, budget_ms=5000, **kwargs)


@pytest.fixture(scope="module")
def verifying_dir(tmp_path_factory):
    """'tiny' (no verify on its card) and 'tinyv', whose card says verify_fused."""
    from itnet.export.onnx_export import export_step
    from itnet.model_card import ModelCard
    from tests.conftest import make_tiny_net

    folder = tmp_path_factory.mktemp("verify")
    net = make_tiny_net()
    export_step(net, ModelCard(name="tiny", category="chair", points=256), folder / "tiny.onnx")
    card = ModelCard(name="tinyv", category="chair", points=256, verify_fused=True)
    export_step(net, card, folder / "tinyv.onnx")
    return folder


def test_the_cards_verify_fused_is_the_default_for_fused_runs_only(verifying_dir, cloud):
    verifying = load_model(verifying_dir / "tinyv.onnx", warm_up=False)
    plain = load_model(verifying_dir / "tiny.onnx", warm_up=False)
    kw = {"budget_ms": 5000, "max_iterations": 2}
    assert "verify" in run_with(verifying, cloud, ensemble=4, **kw).plan.stage_names
    assert (
        "verify" not in run_with(verifying, cloud, ensemble=4, verify=False, **kw).plan.stage_names
    )
    assert (
        "verify" not in run_with(verifying, cloud, **kw).plan.stage_names
    )  # one run: nothing to weigh
    assert (
        "verify"
        not in run_with(verifying, cloud, ensemble=4, up=[0.0, 1.0, 0.0], **kw).plan.stage_names
    )
    assert "verify" not in run_with(plain, cloud, ensemble=4, **kw).plan.stage_names
    single = run_with(verifying, cloud, **kw)
    single.run_to_end()
    assert "verified" not in single.result()


def test_http_stream_and_cli_verify(verifying_dir, tmp_path, cloud):
    from fastapi.testclient import TestClient
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    with TestClient(create_app(Settings(model_dir=verifying_dir))) as client:
        listed = {m["name"]: m for m in client.get("/v1/models").json()["models"]}
        assert listed["tinyv"]["verify_fused"] is True and listed["tiny"]["verify_fused"] is False
        body = {"points": cloud.tolist(), "max_iterations": 2, "budget_ms": 5000}
        asked = {**body, "model": "tiny", "ensemble": 4, "verify": True}
        reply = client.post("/v1/estimate", json=asked)
        assert reply.status_code == 200, reply.text
        assert reply.json()["verified"] is True and reply.json()["ensemble"] == 4
        default = client.post("/v1/estimate", json={**body, "model": "tinyv", "ensemble": 3})
        assert default.json()["verified"] is True
        off = {**body, "model": "tinyv", "ensemble": 3, "verify": False}
        assert "verified" not in client.post("/v1/estimate", json=off).json()
        refused = client.post("/v1/estimate", json={**body, "model": "tiny", "verify": True})
        assert refused.status_code == 422 and "ensemble > 1" in refused.text
        with client.websocket_connect("/v1/estimate/stream") as ws:
            ws.send_json(asked)
            messages = [ws.receive_json() for _ in range(3)]
        assert [m["type"] for m in messages] == ["estimate", "estimate", "result"]
        assert messages[-1]["verified"] is True
    path = tmp_path / "cloud.npy"
    np.save(path, cloud.astype(np.float32))
    args = ["pose", str(path), "--model", "tiny", "--model-dir", str(verifying_dir), "--json"]
    out = CliRunner().invoke(app, [*args, "--ensemble", "3", "--max-iterations", "2", "--verify"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output.strip().splitlines()[-1])["verified"] is True
    out = CliRunner().invoke(app, [*args, "--max-iterations", "2", "--verify"])
    assert out.exit_code != 0 and "ensemble > 1" in out.output


def _fused_report(verify: str, accuracy: float, verified: float | None = None) -> dict:
    """A ``benchmarks.bench_ensemble`` JSON: one run and 4 fused runs on 40 paper views."""
    four = {"accuracy": accuracy, "gain": 2.0, "gain_stderr": 1.0, "scans": 40}
    if verified is not None:
        four |= {"verified": verified,
                 "versus_baseline": {"accuracy": accuracy, "gain": 2.5, "gain_stderr": 0.5}}  # fmt: skip
    one = {"accuracy": 60.0, "gain": 0.0, "gain_stderr": 0.0, "scans": 40}
    return {"machine": "test", "budget_ms": 200.0, "split": "val", "verify": verify,
            "paper": {"1": one, "4": four}}  # fmt: skip


def test_the_card_command_sets_verify_fused_with_its_measurement(tiny_model_dir, tmp_path):
    from typer.testing import CliRunner

    from itnet.cli import app

    out, source = tmp_path / "v.onnx", str(tiny_model_dir / "tiny.onnx")
    bare = CliRunner().invoke(app, ["card", source, "--verify-fused", "--out", str(out)])
    assert bare.exit_code == 2 and "--with-verify" in bare.output and not out.exists()
    (tmp_path / "off.json").write_text(json.dumps(_fused_report("off", 65.0)))
    (tmp_path / "on.json").write_text(json.dumps(_fused_report("on", 67.5, verified=0.95)))
    measured = ["--without-verify", str(tmp_path / "off.json"),
                "--with-verify", str(tmp_path / "on.json")]  # fmt: skip
    half = CliRunner().invoke(app, ["card", source, "--verify-fused", *measured[2:]])
    assert half.exit_code == 2 and "neither" in half.output
    done = CliRunner().invoke(app, ["card", source, "--verify-fused", *measured, "--out", str(out)])
    assert done.exit_code == 0, done.output
    card = load_model(out, warm_up=False).card
    assert card.verify_fused is True
    assert card.verify_evaluation.startswith("fused runs within 200 ms on the val views")
    # the fused rows only, with the paired gain: the one-run row is not verify's to report
    assert "paper 4 runs 65.0% -> 67.5% (+2.5 ± 0.5, 40 scans, 95% verified in time)" in (
        card.verify_evaluation
    )
    assert "60.0" not in card.verify_evaluation
    assert load_model(tiny_model_dir / "tiny.onnx", warm_up=False).card.verify_fused is False
    # the measurement stays on the card: turning the default off and on again needs no report
    for flag in ("--no-verify-fused", "--verify-fused"):
        again = CliRunner().invoke(app, ["card", str(out), flag])
        assert again.exit_code == 0, again.output
    assert load_model(out, warm_up=False).card.verify_fused is True


def test_describe_verify_needs_fused_runs_on_the_same_scans():
    from itnet.model_card import describe_verify

    off, on = _fused_report("off", 65.0), _fused_report("on", 67.5)
    on["paper"]["4"]["scans"] = 41
    with pytest.raises(ValueError, match="different scans"):
        describe_verify(off, on)
    for report in (off, on):
        del report["paper"]["4"]
    with pytest.raises(ValueError, match="more than one run"):
        describe_verify(off, on)


def test_the_python_clients_send_ensemble_and_verify(verifying_dir, cloud):
    """Both bodies of ItnetClient.estimate carry the two fields (JSON, and the binary body's
    query); the result says how many runs were fused and whether verify ran."""
    from fastapi.testclient import TestClient

    from itnet.clients import ItnetClient, ItnetRequestError
    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    with TestClient(create_app(Settings(model_dir=verifying_dir))) as served:
        http = ItnetClient("http://testserver")
        http._http = served  # the app in-process: TestClient is an httpx.Client
        kw = {"model": "tiny", "budget_ms": 5000, "max_iterations": 2}
        for binary in (False, True):
            fused = http.estimate(cloud, ensemble=3, verify=True, binary=binary, **kw)
            assert (fused.ensemble, fused.verified) == (3, True)
            unverified = http.estimate(cloud, ensemble=3, verify=False, binary=binary, **kw)
            assert (unverified.ensemble, unverified.verified) == (3, None)
            single = http.estimate(cloud, binary=binary, **kw)
            assert (single.ensemble, single.verified) == (1, None)
            with pytest.raises(ItnetRequestError, match="ensemble > 1"):
                http.estimate(cloud, verify=True, binary=binary, **kw)
            with pytest.raises(ValueError, match="ensemble"):  # checked before it is sent
                http.estimate(cloud, ensemble=99, binary=binary, **kw)
