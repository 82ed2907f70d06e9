"""The client's wire format, without a server: encoding, URLs, replies, errors, no heavy imports."""

import json
import subprocess
import sys

import numpy as np
import pytest

from itnet.clients import ItnetClient, ItnetClientError, ItnetConnectionError, ItnetRequestError
from itnet.clients.wire import (
    Estimate,
    EstimateResult,
    binary_body,
    json_request,
    parse_message,
    pose_request,
    reply_json,
    request_fields,
    websocket_url,
)
from itnet.pose.request import PoseRequest

POSE = [[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0], [0.0, 0.0, 0.0, 1.0]]
POSE_FIELDS = {"T_canonical_from_input": POSE, "quat_wxyz": [0.7071, 0, 0, 0.7071],
               "quat_xyzw": [0, 0, 0.7071, 0.7071], "translation": [1.0, 2.0, 3.0]}  # fmt: skip


def test_binary_body_is_little_endian_float32_rows():
    points = np.array([[1.0, 2.0, 3.0], [-4.5, 0.25, 1e3]])
    body = binary_body(points)
    assert len(body) == 24
    assert np.array_equal(np.frombuffer(body, dtype="<f4").reshape(-1, 3), points)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        binary_body(np.zeros((4, 2)))


def test_request_fields_and_json_body():
    assert request_fields(PoseRequest(model="chair")) == {"budget_ms": 50.0, "model": "chair"}
    sent = pose_request(PoseRequest(budget_ms=20), {"max_iterations": 7, "model": "tiny"})
    body = json_request([[1, 2, 3]], request_fields(sent))
    assert body == {"points": [[1.0, 2.0, 3.0]], "budget_ms": 20.0, "model": "tiny",
                    "max_iterations": 7}  # fmt: skip
    up = pose_request(None, {"up": np.array([0, -1, 0])})
    assert up.up == [0.0, -1.0, 0.0] and up.to_query() == {"up": "0,-1,0"}
    assert PoseRequest.from_query(up.to_query()) == up
    with pytest.raises(TypeError, match="'budget'"):
        pose_request(None, {"budget": 20})


@pytest.mark.parametrize(
    ("base", "url"),
    [
        ("http://127.0.0.1:8000", "ws://127.0.0.1:8000/v1/estimate/stream"),
        ("https://pose.example.org/itnet/", "wss://pose.example.org/itnet/v1/estimate/stream"),
    ],
)
def test_websocket_url(base, url):
    assert websocket_url(base) == url


def test_replies_parse_into_arrays():
    estimate = {"iteration": 2, **POSE_FIELDS, "elapsed_ms": 3.5, "update_rotation_deg": 0.5,
                "update_translation": 0.01}  # fmt: skip
    reply = {**POSE_FIELDS, "iterations": 2, "stopped_by": "budget", "elapsed_ms": 4.0,
             "model": "chair", "estimates": [estimate]}  # fmt: skip
    result = EstimateResult.from_dict(reply)
    assert result.T_canonical_from_input.shape == (4, 4)
    assert np.allclose(result.T_canonical_from_input, POSE)
    assert result.stopped_by == "budget" and result.iterations == 2
    assert isinstance(result.estimates[0], Estimate) and result.estimates[0].iteration == 2
    with pytest.raises(ItnetClientError, match="malformed reply"):
        EstimateResult.from_dict({"iterations": 1})


def test_errors_carry_status_detail_and_kind():
    body = json.dumps({"detail": "5 points is too few", "kind": "bad_cloud"})
    with pytest.raises(ItnetRequestError) as info:
        reply_json(422, body)
    assert (info.value.status, info.value.kind) == (422, "bad_cloud")
    assert "too few" in str(info.value)
    with pytest.raises(ItnetRequestError, match="HTTP 502: Bad Gateway"):
        reply_json(502, "Bad Gateway")
    with pytest.raises(ItnetRequestError, match="stream error: unknown model") as info:
        parse_message(json.dumps({"type": "error", "detail": "unknown model", "kind": "model"}))
    assert info.value.status is None
    assert parse_message('{"type": "estimate", "iteration": 1}')[0] == "estimate"
    with pytest.raises(ItnetClientError, match="malformed stream message"):
        parse_message("not json")


def test_unreachable_service_is_a_connection_error():
    with ItnetClient("http://127.0.0.1:9", timeout=2) as client:  # port 9: discard, closed
        with pytest.raises(ItnetConnectionError):
            client.estimate(np.zeros((40, 3)))
        with pytest.raises(ItnetConnectionError):
            client.stream(np.zeros((40, 3)))


def test_the_client_imports_neither_torch_nor_the_service():
    code = (
        "import sys, itnet.clients; print(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('torch', 'onnxruntime', 'fastapi') or m.startswith('itnet.service')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
