"""The engine finishes a run's pose by the category's mirror symmetry (itnet.mirror) where the
card declares it, within the budget, and says so in the result."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from itnet.geometry import rotation_angle_deg
from itnet.mirror import mirror_finished
from itnet.pose.errors import BadCloudError
from itnet.pose.runtime import load_model
from itnet.preprocess import pose_from_normalized
from tests.pose_runs import run_with


@pytest.fixture(scope="module")
def mirror_dir(tmp_path_factory: pytest.TempPathFactory, make_net) -> Path:  # type: ignore[no-untyped-def]
    """``tiny.onnx`` (the conftest's tiny network) with a card that declares the mirror."""
    from itnet.export.onnx_export import export_step
    from itnet.model_card import ModelCard

    folder = tmp_path_factory.mktemp("mirror_models")
    card = ModelCard(
        name="tiny", category="chair", points=256, recommended_iterations=5, mirror_planes=["x"]
    )
    export_step(make_net(), card, folder / "tiny.onnx")
    return folder


@pytest.fixture
def mirrored(mirror_dir: Path):  # type: ignore[no-untyped-def]
    return load_model(mirror_dir / "tiny.onnx", threads=1)


@pytest.fixture
def plain(tiny_model_dir: Path):  # type: ignore[no-untyped-def]
    return load_model(tiny_model_dir / "tiny.onnx", threads=1)


@pytest.fixture
def cloud() -> np.ndarray:
    rng = np.random.default_rng(3)
    half = rng.uniform(-1, 1, size=(300, 3)) * [0.4, 0.6, 0.3] + [0.4, 0.0, 0.0]
    shift = np.array([0.5, -1.0, 2.0])  # somewhere off the origin, in its own units
    return np.concatenate([half, half * [-1.0, 1.0, 1.0]]) + shift


def test_the_final_pose_is_the_last_estimate_finished_by_the_mirror(mirrored, cloud):
    run = run_with(mirrored, cloud, budget_ms=10_000, max_iterations=4, converge=(0, 0))
    estimates = list(run)
    result = run.result()
    assert (
        result["mirror"] is True
        and run.result().get("mirror") is True
        and result["mirror_planes"] == ["x"]
    )
    assert result["iterations"] == 4 and [e.iteration for e in estimates] == [1, 2, 3, 4]
    expected = mirror_finished(
        run.points[0].astype(np.float64), estimates[-1].pose_normalized.astype(np.float64), ["x"]
    )
    final = np.asarray(result["T_canonical_from_input"])
    assert np.allclose(final, pose_from_normalized(expected, run.normalization), atol=1e-5)
    assert not np.allclose(final, estimates[-1].pose, atol=1e-4)  # it did move the pose
    assert run.last.update_rotation_deg == pytest.approx(
        float(rotation_angle_deg(final[:3, :3] @ estimates[-1].pose[:3, :3].T)), abs=1e-3
    )
    assert mirrored.mirror_ms != 10.0  # its measured time was folded into the estimate


def test_off_when_asked_or_not_declared_and_refused_for_a_model_without_it(mirrored, plain, cloud):
    off = run_with(mirrored, cloud, budget_ms=10_000, max_iterations=3, mirror=False)
    last = off.run_to_end()
    assert "mirror" not in off.result() and off.result().get("mirror") is None
    assert np.allclose(off.result()["T_canonical_from_input"], last.pose)
    undeclared = run_with(plain, cloud, budget_ms=10_000, max_iterations=3)
    undeclared.run_to_end()
    assert "mirror" not in undeclared.result()
    with pytest.raises(BadCloudError, match="declares no mirror symmetry"):
        run_with(plain, cloud, mirror=True)


def test_ensembles_leave_it_off_unless_asked(mirrored, cloud):
    fused = run_with(mirrored, cloud, budget_ms=10_000, max_iterations=2, ensemble=4)
    assert (
        "mirror" in fused.plan.stage_names
    ) is False  # four fused runs gained nothing from it on validation
    asked = run_with(mirrored, cloud, budget_ms=10_000, max_iterations=2, ensemble=4, mirror=True)
    asked.run_to_end()
    assert asked.result()["mirror"] is True and asked.result()["ensemble"] == 4


def test_a_card_with_mirror_fused_finishes_fused_runs_by_default(mirror_dir, cloud):
    """mirror_fused on the card finishes the ensemble's fused pose too,
    unless the request says not to; a single run is finished either way."""
    model = load_model(mirror_dir / "tiny.onnx", threads=1)
    model.card = model.card.model_copy(update={"mirror_fused": True})
    fused = run_with(model, cloud, budget_ms=10_000, max_iterations=2, ensemble=4)
    fused.run_to_end()
    assert fused.result()["mirror"] is True and fused.result()["ensemble"] == 4
    off = run_with(model, cloud, budget_ms=10_000, max_iterations=2, ensemble=4, mirror=False)
    assert ("mirror" in off.plan.stage_names) is False


def test_skipped_when_the_budget_cannot_hold_it_or_the_run_was_cancelled(mirrored, cloud):
    mirrored.mirror_ms = 1e6  # predicted to take far longer than the budget left
    run = run_with(mirrored, cloud, budget_ms=5_000, max_iterations=3)
    last = run.run_to_end()
    assert run.result()["mirror"] is False
    assert np.allclose(run.result()["T_canonical_from_input"], last.pose)
    assert run.elapsed_ms() < 5_000
    mirrored.mirror_ms = 1.0
    cancelled = run_with(mirrored, cloud, budget_ms=10_000, max_iterations=50)
    cancelled.cancel()
    cancelled.run_to_end()
    assert cancelled.stopped_by == "cancelled" and cancelled.result()["mirror"] is False
    cold = load_model(mirrored.path, threads=1, warm_up=False)  # no idle step time to refuse by
    none = run_with(cold, cloud, budget_ms=1e-3)  # no step fits: nothing to finish
    none.run_to_end()
    assert none.iteration == 0 and none.result()["mirror"] is False


def test_the_service_and_the_cli_pass_it_on(mirror_dir, tiny_model_dir, cloud, tmp_path):
    from fastapi.testclient import TestClient
    from typer.testing import CliRunner

    from itnet.cli import app as cli
    from itnet.service.app import create_app
    from itnet.service.settings import Settings

    body = {"points": cloud.tolist(), "budget_ms": 5000, "max_iterations": 3}
    with TestClient(create_app(Settings(model_dir=mirror_dir))) as client:
        (info,) = client.get("/v1/models").json()["models"]
        assert info["mirror"] is True and info["mirror_planes"] == ["x"]
        assert client.post("/v1/estimate", json=body).json()["mirror"] is True
        assert "mirror" not in client.post("/v1/estimate", json={**body, "mirror": False}).json()
        with client.websocket_connect("/v1/estimate/stream") as ws:
            ws.send_json(body)
            while (message := ws.receive_json())["type"] != "result":
                assert "mirror" not in message  # the estimates are the network's
            assert message["mirror"] is True
    with TestClient(create_app(Settings(model_dir=tiny_model_dir))) as client:
        refused = client.post("/v1/estimate", json={**body, "mirror": True})
        assert refused.status_code == 422 and "mirror" in refused.json()["detail"]
    path = tmp_path / "cloud.npy"
    np.save(path, cloud)
    args = ["pose", str(path), "--model", "tiny", "--model-dir", str(mirror_dir), "--json"]
    row = CliRunner().invoke(cli, args)
    assert row.exit_code == 0, row.output
    assert '"mirror": true' in row.output
    off = CliRunner().invoke(cli, [*args, "--no-mirror"])
    assert off.exit_code == 0 and '"mirror"' not in off.output


def test_planes_are_taken_in_order_as_far_as_the_budget_goes(mirrored, cloud):
    """A card with two planes, and room left for one: the first finishes the pose, the reply
    says which."""
    from dataclasses import dataclass, field

    from itnet.pose.runtime import LoadedModel

    @dataclass
    class RoomForOne(LoadedModel):
        predictions: list[float] = field(default_factory=lambda: [0.0, 1e9])

        def predicted_mirror_ms(self) -> float:
            return self.predictions.pop(0)

    card = mirrored.card.model_copy(update={"mirror_planes": ["x", "z"]})
    model = RoomForOne(card=card, path=mirrored.path, session=mirrored.session)
    run = run_with(model, cloud, budget_ms=10_000, max_iterations=3, converge=(0, 0))
    estimates = list(run)
    assert run.result()["mirror_planes"] == ["x"] and run.result()["mirror"] is True
    expected = mirror_finished(
        run.points[0].astype(np.float64), estimates[-1].pose_normalized.astype(np.float64), ["x"]
    )
    assert np.allclose(run.last.pose_normalized, expected, atol=1e-5)
    both = run_with(mirrored.__class__(card=card, path=mirrored.path, session=mirrored.session),
                      cloud, budget_ms=10_000, max_iterations=3, converge=(0, 0))  # fmt: skip
    both.run_to_end()
    assert both.result()["mirror_planes"] == ["x", "z"]
