"""``model: "auto"`` through HTTP, the WebSocket stream and the CLI, with classifier graphs whose
answer is fixed (always 'chair', always 'table', leaning to 'chair' below the threshold)."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from itnet.cli import app as cli
from itnet.pose.recognition import classify
from itnet.service.app import create_app
from itnet.service.settings import Settings


def _client(folder: Path) -> Iterator[TestClient]:
    with TestClient(create_app(Settings(model_dir=folder, warm_up=False))) as client:
        yield client


@pytest.fixture(scope="module")
def chair_client(chair_dir: Path) -> Iterator[TestClient]:
    yield from _client(chair_dir)


def _post(client: TestClient, cloud: np.ndarray, **fields: object) -> dict:
    reply = client.post("/v1/estimate", json={"points": cloud.tolist(), **fields})
    return {"status": reply.status_code, **reply.json()}


def test_post_auto_runs_the_model_the_classifier_names(chair_client, box_cloud) -> None:
    reply = _post(chair_client, box_cloud, model="auto", budget_ms=2000, max_iterations=3)
    assert reply["status"] == 200, reply
    assert reply["category"] == "chair" and reply["model"] == "chair"
    assert reply["category_probability"] > 0.99 and reply["unsure"] is False
    assert reply["candidates"][0]["category"] == "chair"
    assert len(reply["candidates"]) == 3
    probabilities = [c["probability"] for c in reply["candidates"]]
    assert probabilities == sorted(probabilities, reverse=True)
    assert reply["iterations"] == 3 and len(reply["estimates"]) == 3
    # the classification is inside the request's time, which the budget bounds
    assert 0 < reply["classify_ms"] <= reply["elapsed_ms"]
    named = _post(chair_client, box_cloud, model="chair", budget_ms=2000, max_iterations=3)
    np.testing.assert_allclose(
        named["T_canonical_from_input"], reply["T_canonical_from_input"], atol=1e-6
    )
    assert "category" not in named or named["category"] is None


def test_auto_classification_counts_against_the_budget(chair_client, box_cloud) -> None:
    """A budget the classification alone spends gets no pose: a refusal, not the start."""
    reply = _post(chair_client, box_cloud, model="auto", budget_ms=0.001)
    assert reply["status"] in (422, 503) and reply["kind"] in ("budget_too_small", "overloaded")


def test_stream_says_the_category_first(chair_client, box_cloud) -> None:
    request = {"points": box_cloud.tolist(), "model": "auto", "budget_ms": 2000,
               "max_iterations": 2}  # fmt: skip
    with chair_client.websocket_connect("/v1/estimate/stream") as ws:
        ws.send_text(json.dumps(request))
        messages = [ws.receive_json()]
        while messages[-1]["type"] != "result":
            messages.append(ws.receive_json())
    assert [m["type"] for m in messages] == ["category", "estimate", "estimate", "result"]
    assert messages[0]["category"] == "chair" and messages[0]["model"] == "chair"
    assert messages[0]["unsure"] is False and len(messages[0]["candidates"]) == 3
    assert messages[-1]["category"] == "chair" and messages[-1]["iterations"] == 2


def test_models_lists_auto(chair_client) -> None:
    auto = chair_client.get("/v1/models").json()["auto"]
    assert auto["classes"] == ["chair", "table", "sofa"]
    assert auto["threshold"] == 0.5 and auto["accuracy"] == 0.9
    assert auto["models"] == {"chair": "chair", "table": None, "sofa": None}
    assert auto["sizes"] is None  # no size prior in this card: a request's unit is not used


def test_category_without_a_pose_model_is_a_clear_422(table_dir: Path, box_cloud) -> None:
    for client in _client(table_dir):
        reply = _post(client, box_cloud, model="auto")
        assert reply["status"] == 422 and reply["kind"] == "no_pose_model"
        assert "table" in reply["detail"] and "sofa" in reply["detail"]  # candidates named
        assert "loaded: chair" in reply["detail"]
        with client.websocket_connect("/v1/estimate/stream") as ws:
            ws.send_text(json.dumps({"points": box_cloud.tolist(), "model": "auto"}))
            message = ws.receive_json()
        assert message["type"] == "error" and message["kind"] == "no_pose_model"
        # the service keeps serving: a named model still works
        assert _post(client, box_cloud, model="chair")["status"] == 200


def test_unsure_recognition_says_so(unsure_dir: Path, box_cloud) -> None:
    for client in _client(unsure_dir):
        reply = _post(client, box_cloud, model="auto", max_iterations=1, budget_ms=2000)
        assert reply["status"] == 200 and reply["category"] == "chair"
        assert reply["unsure"] is True and reply["category_probability"] < 0.6


@pytest.mark.timing
def test_an_unsure_request_gets_a_second_opinion_within_half_its_budget(
    unsure_dir: Path, box_cloud, tmp_path
) -> None:
    """The fixed classifier stays unsure however it looks: with room in the budget the reply is
    the 4 looks' (said so), not without it, nor when the service is told never (setting 1)."""
    for client in _client(unsure_dir):
        auto = client.get("/v1/models").json()["auto"]
        assert auto["second_looks"] == 4 and auto["cascade"] is None  # a one-head graph
        reply = _post(client, box_cloud, model="auto", max_iterations=1, budget_ms=2000)
        assert reply["status"] == 200 and reply["unsure"] is True
        assert reply["second_opinion"] is True and reply["classify_looks"] == 4
        classifier = client.app.state.service.classifier  # type: ignore[attr-defined]
        hurried = classify(classifier, box_cloud, deadline=time.perf_counter()).as_dict()
        assert hurried["category"] == "chair"
        assert "second_opinion" not in hurried and "classify_looks" not in hurried
    settings = Settings(model_dir=unsure_dir, warm_up=False, classify_second_looks=1)
    with TestClient(create_app(settings)) as client:
        assert client.get("/v1/models").json()["auto"]["second_looks"] == 1
        never = _post(client, box_cloud, model="auto", max_iterations=1, budget_ms=2000)
        assert never["unsure"] is True and "second_opinion" not in never
    path = _write_cloud(tmp_path / "box.npy", box_cloud)
    common = [str(path), "--model-dir", str(unsure_dir), "--json"]
    assert json.loads(CliRunner().invoke(cli, ["classify", *common]).stdout)["classify_looks"] == 4
    once = json.loads(CliRunner().invoke(cli, ["classify", *common, "--second-looks", "1"]).stdout)
    assert once["unsure"] is True and "classify_looks" not in once
    posed = CliRunner().invoke(cli, ["pose", *common, "--model", "auto", "--max-iterations", "1"])
    assert posed.exit_code == 0, posed.output
    assert json.loads(posed.stdout.splitlines()[-1])["second_opinion"] is True


def test_auto_without_a_classifier_says_none_is_loaded(pose_dir: Path, box_cloud) -> None:
    for client in _client(pose_dir):
        assert client.get("/v1/models").json()["auto"] is None
        reply = _post(client, box_cloud, model="auto")
        assert reply["status"] == 422 and reply["kind"] == "no_classifier"


def _write_cloud(path: Path, cloud: np.ndarray) -> Path:
    np.save(path, cloud)
    return path


def test_cli_pose_classify_and_align_auto(chair_dir: Path, table_dir: Path, tmp_path, box_cloud):
    runner = CliRunner()
    a = _write_cloud(tmp_path / "a.npy", box_cloud)
    b = _write_cloud(tmp_path / "b.npy", box_cloud[::-1] + 1.0)
    common = ["--model-dir", str(chair_dir), "--json"]
    out = runner.invoke(cli, ["pose", str(a), str(b), "--model", "auto", *common])
    assert out.exit_code == 0, out.output
    lines = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(lines) == 2 and all(
        r["category"] == "chair" and r["model"] == "chair" for r in lines
    )

    out = runner.invoke(cli, ["classify", str(a), str(b), *common])
    assert out.exit_code == 0, out.output
    lines = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r["file"] for r in lines] == [str(a), str(b)]
    assert all(r["category"] == "chair" and len(r["candidates"]) == 3 for r in lines)

    out = runner.invoke(cli, ["pose", str(a), "--model", "auto", "--model-dir", str(table_dir)])
    assert out.exit_code == 2 and "no table pose model" in out.output

    out = runner.invoke(
        cli, ["align", str(a), str(b), "--model", "auto", *common, "--no-refine", "--starts", "1"]
    )
    assert out.exit_code == 0, out.output
    assert json.loads(out.stdout.splitlines()[-1])["model"] == "chair"
    assert "auto: chair" in out.output


def test_cli_classify_without_a_classifier_or_with_a_bad_file(
    pose_dir: Path, chair_dir: Path, tmp_path: Path, box_cloud
) -> None:
    runner = CliRunner()
    a = _write_cloud(tmp_path / "a.npy", box_cloud)
    out = runner.invoke(cli, ["classify", str(a), "--model-dir", str(pose_dir)])
    assert out.exit_code == 2 and "no category classifier" in out.output
    flat = _write_cloud(tmp_path / "flat.npy", np.zeros((100, 3), np.float32))
    out = runner.invoke(cli, ["classify", str(flat), str(a), "--model-dir", str(chair_dir)])
    assert out.exit_code == 2 and "degenerate" in out.output
    assert f"{a}: chair" in out.output  # the good file is still classified


def test_handed_in_pose_models_still_get_the_classifier(chair_dir: Path, box_cloud) -> None:
    """``itnet serve`` loads the pose models before binding and hands them to the app."""
    from itnet.pose.runtime import load_models

    models = load_models(chair_dir, warm_up=False)
    settings = Settings(model_dir=chair_dir, warm_up=False)
    with TestClient(create_app(settings, models=models)) as client:
        assert client.get("/v1/models").json()["auto"]["classes"] == ["chair", "table", "sofa"]
        assert _post(client, box_cloud, model="auto", max_iterations=1)["category"] == "chair"


class _LooksRecorder:
    """A stand-in classifier: its answer leans with the first point's x, so turned looks give
    different probabilities; it keeps every batch it was given."""

    def __init__(self) -> None:
        from itnet.model_card import ClassifierCard

        self.card = ClassifierCard(classes=["chair", "table"], accuracy=0.9, threshold=0.5,
                                   points=64)  # fmt: skip
        self.batches: list[np.ndarray] = []
        self.upright = None  # no upright classifier beside it

    def probabilities(self, x: np.ndarray) -> np.ndarray:
        self.batches.append(x)
        logits = np.stack([x[:, :, 0].mean(1), -x[:, :, 0].mean(1)], axis=1) * 5
        e = np.exp(logits - logits.max(1, keepdims=True))
        return e / e.sum(1, keepdims=True)


def test_several_looks_are_turned_subsets_averaged_in_the_log_domain(box_cloud) -> None:
    from itnet.geometry import viewing_axis_turns
    from itnet.pose.errors import BadCloudError
    from itnet.pose.recognition import classify
    from itnet.preprocess import estimate_normalization

    stand_in = _LooksRecorder()
    one = classify(stand_in, box_cloud)
    assert stand_in.batches[-1].shape == (1, 64, 3) and "classify_looks" not in one.as_dict()
    four = classify(stand_in, box_cloud, looks=4)
    looks = stand_in.batches[-1]
    assert looks.shape == (4, 64, 3) and four.as_dict()["classify_looks"] == 4
    normalized = estimate_normalization(box_cloud).apply(box_cloud)
    for turn, look in zip(viewing_axis_turns(4), looks, strict=True):
        back = look @ turn  # each look is a subset of the cloud, turned about z
        nearest = np.abs(back[:, None, :] - normalized[None]).max(-1).min(1)
        assert nearest.max() < 1e-5
    p = stand_in.probabilities(looks)
    mean_log = np.log(p).mean(0)
    expected = np.exp(mean_log - mean_log.max()) / np.exp(mean_log - mean_log.max()).sum()
    got = {c.category: c.probability for c in four.candidates}
    np.testing.assert_allclose([got["chair"], got["table"]], expected, rtol=1e-6)
    with pytest.raises(BadCloudError, match="looks"):
        classify(stand_in, box_cloud, looks=17)


def test_an_unsure_look_is_followed_by_the_rest_of_the_looks(box_cloud) -> None:
    """Unsure after one look (a threshold over what the stand-in gives): 3 more looks, turned,
    and the answer is the same as asking for 4; sure, or asked never, or out of time: one."""
    from itnet.pose.errors import BadCloudError
    from itnet.pose.recognition import classify

    stand_in = _LooksRecorder()
    sure = classify(stand_in, box_cloud)  # threshold 0.5 of 2 classes: always sure
    assert not sure.second_opinion and [len(b) for b in stand_in.batches] == [1]
    stand_in.card = stand_in.card.model_copy(update={"threshold": 0.9999})
    stand_in.batches.clear()
    second = classify(stand_in, box_cloud, second_looks=4)
    assert second.second_opinion and second.looks == 4 and second.unsure
    assert [len(b) for b in stand_in.batches] == [1, 3]  # the first look is not taken again
    assert second.as_dict()["second_opinion"] is True and second.as_dict()["classify_looks"] == 4
    four = classify(stand_in, box_cloud, looks=4, second_looks=4)
    assert not four.second_opinion  # K looks asked for: no second opinion after them
    np.testing.assert_allclose(stand_in.batches[-1][0], stand_in.batches[0][0])
    np.testing.assert_allclose(stand_in.batches[-1][1:], stand_in.batches[1])
    assert [c.probability for c in second.candidates] == pytest.approx(
        [c.probability for c in four.candidates], rel=1e-9
    )
    assert second.probability != pytest.approx(sure.probability)
    for late in (classify(stand_in, box_cloud, second_looks=1),
                 classify(stand_in, box_cloud, deadline=time.perf_counter() - 1.0)):  # fmt: skip
        assert late.unsure and not late.second_opinion and late.looks == 1
        assert "second_opinion" not in late.as_dict()
    with pytest.raises(BadCloudError, match="second_looks"):
        classify(stand_in, box_cloud, second_looks=0)


def test_a_small_cloud_reaches_the_classifier_shuffled(box_cloud) -> None:
    """A cloud of fewer points than the card's reaches the graph whole but not in its rows'
    order: a canonicaliser that sees the first points (card.canonical_points) gets a random
    sample of the object, not one end of a depth image."""
    from itnet.pose.recognition import classify
    from itnet.preprocess import estimate_normalization

    stand_in = _LooksRecorder()
    scan = box_cloud[np.argsort(box_cloud[:, 0])][:50]  # 50 < 64 points, in order along x
    classify(stand_in, scan)
    (seen,) = stand_in.batches[-1]
    normalized = estimate_normalization(scan).apply(scan)
    assert seen.shape == (50, 3)
    np.testing.assert_allclose(np.sort(seen[:, 0]), normalized[:, 0], atol=1e-6)  # all of it
    assert not np.all(np.diff(seen[:, 0]) >= 0)  # in another order
    assert seen[:12, 0].max() > np.median(normalized[:, 0])  # the first reach across it


def test_the_ensemble_also_classifies_with_as_many_looks(
    chair_client, chair_dir: Path, box_cloud, tmp_path
) -> None:
    reply = _post(chair_client, box_cloud, model="auto", budget_ms=2000, max_iterations=2,
                  ensemble=4)  # fmt: skip
    assert reply["status"] == 200, reply
    assert reply["classify_looks"] == 4 and reply["ensemble"] == 4 and reply["category"] == "chair"
    plain = _post(chair_client, box_cloud, model="auto", budget_ms=2000, max_iterations=2)
    assert "classify_looks" not in plain
    path = tmp_path / "box.npy"
    np.save(path, box_cloud)
    common = ["--model-dir", str(chair_dir), "--json"]
    out = CliRunner().invoke(cli, ["classify", str(path), "--looks", "3", *common])
    assert out.exit_code == 0, out.output
    assert json.loads(out.stdout.splitlines()[-1])["classify_looks"] == 3
    posed = CliRunner().invoke(cli, ["pose", str(path), "--model", "auto", "--ensemble", "2",
                                     "--max-iterations", "2", *common])  # fmt: skip
    assert posed.exit_code == 0, posed.output
    row = json.loads(posed.stdout.splitlines()[-1])
    assert row["classify_looks"] == 2 and row["ensemble"] == 2
