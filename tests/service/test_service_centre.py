"""The centre correction through the service: on by default where the card has one, off when a
request says ``"centre": false``, listed by ``GET /v1/models``, refused for a model without."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from itnet.centre import FEATURE_COUNT, CentreCorrection
from itnet.service.app import create_app
from itnet.service.settings import Settings

OFFSET = [0.05, -0.02, 0.1]  # the correction's constant prediction, normalised units


@pytest.fixture(scope="module")
def centred(
    tmp_path_factory: pytest.TempPathFactory, export_model, settings: Settings
) -> Iterator[TestClient]:  # type: ignore[no-untyped-def]
    from itnet.model_card import ModelCard

    folder: Path = tmp_path_factory.mktemp("centred_models")
    weights = np.zeros((FEATURE_COUNT + 1, 3))
    weights[-1] = OFFSET
    correction = CentreCorrection(np.zeros(FEATURE_COUNT), np.ones(FEATURE_COUNT), weights)
    card = ModelCard(name="tiny", category="chair", points=256, recommended_iterations=3,
                     centre_correction=correction.to_dict(), centre_evaluation="measured")  # fmt: skip
    export_model(card, folder / "tiny.onnx")
    with TestClient(create_app(Settings(model_dir=folder, limits=settings.limits))) as client:
        yield client


def _post(client: TestClient, points: list, **fields: object) -> dict:
    reply = client.post("/v1/estimate", json={"points": points, "budget_ms": 2000, **fields})
    assert reply.status_code == 200, reply.text
    return reply.json()


def test_the_centre_is_finished_unless_the_request_says_not_to(
    centred: TestClient, make_cloud
) -> None:  # type: ignore[no-untyped-def]
    cloud = make_cloud()
    on, off = _post(centred, cloud.tolist()), _post(centred, cloud.tolist(), centre=False)
    assert on["centre"] is True and off.get("centre") is None
    assert np.allclose(on["quat_wxyz"], off["quat_wxyz"], atol=1e-6)  # the rotation is kept
    scale = float(np.sqrt(((cloud - cloud.mean(0)) ** 2).sum(1).mean()))
    moved = np.subtract(on["translation"], off["translation"])
    assert np.allclose(moved, -np.array(OFFSET) * scale, atol=1e-4)
    (info,) = centred.get("/v1/models").json()["models"]
    assert info["centre"] is True and info["centre_evaluation"] == "measured"


def test_a_model_without_a_correction_says_so(client: TestClient, make_cloud) -> None:  # type: ignore[no-untyped-def]
    reply = client.post(
        "/v1/estimate", json={"points": make_cloud().tolist(), "budget_ms": 500, "centre": True}
    )
    assert reply.status_code == 422 and "no centre correction" in reply.json()["detail"]
    assert client.get("/v1/models").json()["models"][0]["centre"] is False


def test_a_viewpoint_is_taken_from_json_and_from_a_binary_query(
    centred: TestClient, make_cloud
) -> None:  # type: ignore[no-untyped-def]
    cloud = make_cloud()
    as_json = _post(centred, cloud.tolist(), viewpoint=[0, 0, 0])
    reply = centred.post(
        "/v1/estimate", content=cloud.astype("<f4").tobytes(),
        params={"budget_ms": 2000, "viewpoint": "0,0,0"},
        headers={"content-type": "application/octet-stream"},
    )  # fmt: skip
    assert reply.status_code == 200, reply.text
    # this card has no viewpoint correction: the plain one finishes the centre, and says so
    for result in (as_json, reply.json()):
        assert result["centre"] is True and result["centre_viewpoint"] is False
    for bad in ([0, 0], "1,2", [0, "x", 1]):
        refused = centred.post(
            "/v1/estimate", json={"points": cloud.tolist(), "budget_ms": 500, "viewpoint": bad}
        )
        assert refused.status_code == 422 and "viewpoint" in refused.text, refused.text


def test_alignment_through_the_service_weighs_the_in_process_poses(
    centred: TestClient, make_cloud
) -> None:  # type: ignore[no-untyped-def]
    """itnet-align --server (POST /v1/align) and in-process weigh the same served poses, the
    centre correction included, and give the same answer."""
    from itnet.alignment import align
    from itnet.alignment.request import AlignRequest
    from itnet.clients import ItnetClient

    client = ItnetClient("http://testserver")
    client._http = centred  # the app in-process: TestClient is an httpx.Client
    catalog = centred.app.state.service.catalog  # type: ignore[attr-defined]
    cloud = make_cloud().astype(np.float64)
    other = cloud + np.array([0.2, -0.1, 0.05])
    request = AlignRequest(model="tiny", budget_ms=5000, max_iterations=3, refine=False)
    remote = client.align(cloud, other, request)
    local = align(catalog, cloud, other, request)
    assert local.pose_a.result["centre"] is True and local.pose_b.result["centre"] is True
    pose_a = remote["T_canonical_from_a"]["T_canonical_from_input"]
    assert np.allclose(pose_a, local.pose_a.T_canonical_from_input, atol=1e-6)
    assert np.allclose(remote["T_b_from_a"], local.T_b_from_a, atol=1e-6)
