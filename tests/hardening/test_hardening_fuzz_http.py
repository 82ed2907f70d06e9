"""Schema-based and property-based fuzzing of the HTTP and WebSocket API, in process (ASGI).

No input makes a 5xx, every error is the documented ``{"detail", "kind"}`` body, responses match
the OpenAPI schema, and afterwards the service is healthy (no slot held, a good request works).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hardening_helpers import scaled
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)
from starlette.websockets import WebSocketDisconnect

from itnet.pose.runtime import LoadedModel
from itnet.service.app import create_app
from itnet.service.settings import Settings

# Not positive_data_acceptance: the schema cannot say "at least 32 distinct finite points".
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance,
          response_schema_conformance]  # fmt: skip
EXAMPLES = {"POST /v1/estimate": scaled(300)}
FUZZ = settings(deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
ERROR_STATUSES = {400, 404, 408, 413, 415, 422, 503}


@pytest.fixture(scope="module")
def app(settings: Settings, tiny: LoadedModel) -> Any:
    return create_app(settings, {"tiny": tiny})


@pytest.fixture(scope="module")
def client(app: Any) -> Iterator[TestClient]:
    with TestClient(app) as test_client:
        yield test_client


def assert_healthy(client: TestClient, points: list) -> None:
    assert client.app.state.service.gate.active == 0  # type: ignore[attr-defined]
    assert 'status="500"' not in client.get("/metrics").text
    reply = client.post("/v1/estimate", json={"points": points, "max_iterations": 2})
    assert reply.status_code == 200 and reply.json()["iterations"] == 2


def fuzz_operation(operation: Any, max_examples: int) -> dict[int, int]:
    """Schema-valid and schema-violating requests to one operation; the statuses they got."""
    statuses: dict[int, int] = {}
    strategy = operation.as_strategy(
        generation_mode=GenerationMode.POSITIVE
    ) | operation.as_strategy(generation_mode=GenerationMode.NEGATIVE)

    @settings(FUZZ, max_examples=max_examples)
    @given(case=strategy)
    def call(case: Any) -> None:
        response = case.call()
        statuses[response.status_code] = statuses.get(response.status_code, 0) + 1
        case.validate_response(response, checks=CHECKS)

    call()
    return statuses


def test_schemathesis_finds_no_server_error(app: Any, client: TestClient, points: list) -> None:
    """Every operation of /openapi.json."""
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    seen: dict[str, dict[int, int]] = {}
    for result in schema.get_all_operations():
        operation = result.ok()
        label = f"{operation.method.upper()} {operation.path}"
        seen[label] = fuzz_operation(operation, EXAMPLES.get(label, scaled(20)))
    assert set(seen) >= {"POST /v1/estimate", "GET /v1/models", "GET /readyz", "GET /metrics"}
    assert not [s for counts in seen.values() for s in counts if s >= 500], seen
    assert len(seen["POST /v1/estimate"]) >= 2, seen  # several kinds of answer were reached
    assert_healthy(client, points)


KEYS = st.sampled_from(["points", "budget_ms", "max_iterations", "model", "type", "x"])
json_values = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=8),
    lambda children: st.lists(children, max_size=6) | st.dictionaries(KEYS, children, max_size=5),
    max_leaves=40,
)


@settings(FUZZ, max_examples=scaled(200))
@given(document=json_values)
def test_any_json_document_gets_an_answer_not_a_500(client: TestClient, document: Any) -> None:
    body = json.dumps(document, allow_nan=True)
    reply = client.post("/v1/estimate", content=body, headers={"content-type": "application/json"})
    assert reply.status_code == 200 or reply.status_code in ERROR_STATUSES, reply.text
    if reply.status_code != 200:
        assert set(reply.json()) == {"detail", "kind"} and reply.json()["detail"]


@settings(FUZZ, max_examples=scaled(150))
@given(
    body=st.binary(max_size=3000),
    content_type=st.sampled_from(["application/octet-stream", "application/json",
        "application/vnd.x+json", "APPLICATION/OCTET-STREAM; charset=latin-1", "text/plain",
        "multipart/form-data; boundary=x", "", ";;;", "application/json; charset=utf-16"]),
    query=st.dictionaries(st.sampled_from(["budget_ms", "max_iterations", "model", "zzz"]),
                          st.text(max_size=12), max_size=3),
)  # fmt: skip
def test_any_bytes_type_and_query_get_an_answer_not_a_500(
    client: TestClient, body: bytes, content_type: str, query: dict[str, str]
) -> None:
    headers = {"content-type": content_type} if content_type else {}
    reply = client.post("/v1/estimate", content=body, headers=headers, params=query)
    assert reply.status_code == 200 or reply.status_code in ERROR_STATUSES, reply.text
    assert reply.headers["content-type"] == "application/json"


@settings(FUZZ, max_examples=scaled(80))
@given(message=st.one_of(json_values.map(lambda v: json.dumps(v, allow_nan=True)),
                         st.text(max_size=200), st.binary(min_size=1, max_size=200)))  # fmt: skip
def test_any_first_stream_message_gets_a_result_or_an_error_close(
    client: TestClient, message: str | bytes
) -> None:
    with client.websocket_connect("/v1/estimate/stream") as ws:
        if isinstance(message, bytes):
            ws.send_bytes(message)
        else:
            ws.send_text(message)
        while (reply := ws.receive_json())["type"] == "estimate":
            pass
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
    if reply["type"] == "result":
        assert closed.value.code == 1000
    else:
        assert reply["type"] == "error" and reply["detail"], reply
        assert closed.value.code in (1003, 1008, 1009), (closed.value.code, reply)


def test_the_service_is_healthy_after_the_fuzzing(client: TestClient, points: list) -> None:
    assert_healthy(client, points)
    assert 'status="ws_1011"' not in client.get("/metrics").text
