"""``up`` through the service: JSON field, binary query, the clients, the WebSocket stream; the
reply holds the pose upright and says so; a bad up is a 422 that says what is wrong; a model
whose card requires it refuses a request without it, and GET /v1/models lists that."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from itnet.service.app import create_app
from itnet.service.settings import Settings
from itnet.upright import UP, unit_up

TILTED_UP = [0.1, -1.0, 0.3]


def _upright(result: dict, up: list[float]) -> bool:
    rotation = np.asarray(result["T_canonical_from_input"])[:3, :3]
    return bool(np.allclose(rotation @ unit_up(up), UP, atol=1e-4))


def test_up_from_json_and_from_a_binary_query_holds_the_pose_upright(
    client: TestClient, make_cloud
) -> None:  # type: ignore[no-untyped-def]
    cloud = make_cloud()
    as_json = client.post(
        "/v1/estimate", json={"points": cloud.tolist(), "budget_ms": 2000, "up": TILTED_UP}
    )
    as_binary = client.post(
        "/v1/estimate", content=cloud.astype("<f4").tobytes(),
        params={"budget_ms": 2000, "up": ",".join(map(str, TILTED_UP))},
        headers={"content-type": "application/octet-stream"},
    )  # fmt: skip
    for reply in (as_json, as_binary):
        assert reply.status_code == 200, reply.text
        result = reply.json()
        assert result["iterations"] >= 1 and _upright(result, TILTED_UP)
        assert np.allclose(result["up"], unit_up(TILTED_UP), atol=1e-6)
    free = client.post("/v1/estimate", json={"points": cloud.tolist(), "budget_ms": 2000})
    assert "up" not in free.json() or free.json()["up"] is None


def test_a_bad_up_is_refused_with_what_is_wrong(client: TestClient, make_cloud) -> None:  # type: ignore[no-untyped-def]
    points = make_cloud().tolist()
    for bad in ([0, 0, 0], [0, 1], "1,x,2", [0, 1, 2, 3]):
        reply = client.post("/v1/estimate", json={"points": points, "budget_ms": 500, "up": bad})
        assert reply.status_code == 422 and "up" in reply.text, (bad, reply.text)


def test_the_stream_holds_every_estimate_upright(client: TestClient, make_cloud) -> None:  # type: ignore[no-untyped-def]
    with client.websocket_connect("/v1/estimate/stream") as ws:
        ws.send_json({"points": make_cloud().tolist(), "budget_ms": 2000, "up": TILTED_UP})
        messages = []
        while not messages or messages[-1]["type"] != "result":
            messages.append(ws.receive_json())
            assert messages[-1]["type"] in ("estimate", "result"), messages[-1]
    estimates = messages[:-1]
    assert estimates and all(_upright(m, TILTED_UP) for m in estimates)
    assert _upright(messages[-1], TILTED_UP)


@pytest.fixture(scope="module")
def needs_up(
    tmp_path_factory: pytest.TempPathFactory, export_model, settings: Settings
) -> Iterator[TestClient]:  # type: ignore[no-untyped-def]
    from itnet.centre import FEATURE_COUNT, CentreCorrection
    from itnet.model_card import ModelCard

    folder: Path = tmp_path_factory.mktemp("up_models")
    weights = np.zeros((FEATURE_COUNT + 1, 3))
    weights[-1] = [0.02, 0.0, 0.0]  # the centre's offset, whatever the cloud: only its use shows
    upright_centre = CentreCorrection(np.zeros(FEATURE_COUNT), np.ones(FEATURE_COUNT), weights)
    card = ModelCard(name="box", category="dresser", points=256, recommended_iterations=3,
                     requires_up=True, up_evaluation="measured with up",
                     centre_correction_up=upright_centre.to_dict())  # fmt: skip
    export_model(card, folder / "box.onnx")
    with TestClient(create_app(Settings(model_dir=folder, limits=settings.limits))) as client:
        yield client


def test_a_model_that_requires_up_refuses_a_request_without_it(
    needs_up: TestClient, make_cloud
) -> None:  # type: ignore[no-untyped-def]
    points = make_cloud().tolist()
    refused = needs_up.post("/v1/estimate", json={"points": points, "budget_ms": 500})
    assert refused.status_code == 422 and "needs 'up'" in refused.json()["detail"]
    served = needs_up.post(
        "/v1/estimate", json={"points": points, "budget_ms": 2000, "up": [0, 1, 0]}
    )
    assert served.status_code == 200 and _upright(served.json(), [0, 1, 0])
    # the card's only centre correction is the one fitted held upright: it finished the pose
    assert served.json()["centre"] is True and served.json()["centre_up"] is True
    (info,) = needs_up.get("/v1/models").json()["models"]
    assert info["requires_up"] is True and info["up_evaluation"] == "measured with up"
    assert info["centre_up"] is True and info["centre"] is False


def test_the_clients_send_up(client: TestClient, make_cloud) -> None:  # type: ignore[no-untyped-def]
    from itnet.clients.wire import pose_request, request_fields

    sent = pose_request(None, {"budget_ms": 2000.0, "model": "tiny", "up": TILTED_UP})
    fields = request_fields(sent)
    assert fields["up"] == [0.1, -1.0, 0.3] and sent.to_query()["up"] == "0.1,-1,0.3"
    reply = client.post("/v1/estimate", json={"points": make_cloud().tolist(), **fields})
    assert reply.status_code == 200 and _upright(reply.json(), TILTED_UP)


def test_alignment_runs_with_up_through_the_service_match_the_in_process_runs(
    client: TestClient, make_cloud
) -> None:  # type: ignore[no-untyped-def]
    """itnet-align --server with up (POST /v1/align with up_a, up_b): the same request as
    in-process, so the same poses and runs, every one of them upright, and the same answer."""
    from itnet.alignment import align
    from itnet.alignment.request import AlignRequest
    from itnet.clients import ItnetClient

    http = ItnetClient("http://testserver")
    http._http = client  # the app in-process: TestClient is an httpx.Client
    catalog = client.app.state.service.catalog  # type: ignore[attr-defined]
    cloud, up = make_cloud().astype(np.float64), unit_up(TILTED_UP)
    ups = [float(v) for v in up]
    request = AlignRequest(model="tiny", budget_ms=5000, max_iterations=3, refine=False,
                           up_a=ups, up_b=ups)  # fmt: skip
    remote = http.align(cloud, cloud, request)
    local = align(catalog, cloud, cloud, request)
    assert np.allclose(remote["T_b_from_a"], local.T_b_from_a, atol=1e-6)
    assert remote["up_a"] == pytest.approx(ups) and remote["up_b"] == pytest.approx(ups)
    for pose in (*local.pose_a.candidates(), *local.pose_b.candidates()):
        assert np.allclose(pose[:3, :3] @ up, UP, atol=1e-4)
