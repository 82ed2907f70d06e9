"""Every bad request gets its 4xx with a message saying what is wrong, and the next one works."""

from __future__ import annotations

import json
from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

GOOD = np.random.default_rng(7).uniform(-1, 1, size=(200, 3)).round(4).tolist()
JSON = {"content-type": "application/json"}
BINARY = {"content-type": "application/octet-stream"}


def f32(points: list[list[float]] | np.ndarray) -> bytes:
    return np.asarray(points, dtype="<f4").tobytes()


def body(**fields: object) -> bytes:
    return json.dumps({"points": GOOD, **fields}).encode()


# (name, body bytes, headers, query, status, words the message must contain)
CASES = [
    ("nan json", b'{"points": [[NaN, 0, 0]' + b", [1, 2, 3]" * 40 + b"]}", JSON, {}, 422, "NaN"),
    ("inf binary", f32([[np.inf, 0, 0], *GOOD]), BINARY, {}, 422, "infinite"),
    ("empty points", body().replace(json.dumps(GOOD).encode(), b"[]"), JSON, {}, 422, "empty"),
    ("empty json body", b"", JSON, {}, 400, "empty"),
    ("empty binary body", b"", BINARY, {}, 422, "empty"),
    ("too few", json.dumps({"points": GOOD[:10]}).encode(), JSON, {}, 422, "too few"),
    ("too many", f32(np.resize(GOOD, (5000, 3))), BINARY, {}, 422, "too many"),
    ("two coordinates", json.dumps({"points": [p[:2] for p in GOOD]}).encode(), JSON, {}, 422,
     "at least 3"),
    ("four coordinates", json.dumps({"points": [[*p, 1] for p in GOOD]}).encode(), JSON, {}, 422,
     "at most 3"),
    ("points not a list", body().replace(json.dumps(GOOD).encode(), b'"abc"'), JSON, {}, 422,
     "points"),
    ("no points", b'{"budget_ms": 5}', JSON, {}, 422, "points: Field required"),
    ("not an object", b"[[1, 2, 3]]", JSON, {}, 422, "JSON object"),
    ("all points equal", json.dumps({"points": [[1.5, 2, 3]] * 100}).encode(), JSON, {}, 422,
     "degenerate"),
    ("budget zero", body(budget_ms=0), JSON, {}, 422, "budget_ms"),
    ("budget negative", body(budget_ms=-5), JSON, {}, 422, "greater than 0"),
    ("budget over the limit", body(budget_ms=1e9), JSON, {}, 422, "over the limit"),
    ("budget not a number", body(budget_ms="soon"), JSON, {}, 422, "budget_ms"),
    ("iterations zero", body(max_iterations=0), JSON, {}, 422, "max_iterations"),
    ("iterations over the limit", body(max_iterations=10_000), JSON, {}, 422, "over the limit"),
    ("unknown field", body(budget=5), JSON, {}, 422, "budget: Extra inputs"),
    ("unknown model", body(model="sofa"), JSON, {}, 404, "unknown model 'sofa'"),
    ("unknown model binary", f32(GOOD), BINARY, {"model": "sofa"}, 404, "unknown model"),
    ("malformed json", b'{"points": [[1, 2, 3]', JSON, {}, 400, "malformed JSON"),
    ("truncated binary", f32(GOOD)[:-5], BINARY, {}, 400, "not a multiple of 12"),
    ("bad query", f32(GOOD), BINARY, {"budget_ms": "x"}, 422, "budget_ms"),
    ("unknown query", f32(GOOD), BINARY, {"budgetms": "5"}, 422, "budgetms"),
    ("oversize", b"0" * (300 * 1024), BINARY, {}, 413, "exceeds the limit"),
    ("wrong type", body(), {"content-type": "text/plain"}, {}, 415, "Content-Type"),
    ("no type", body(), {}, {}, 415, "no Content-Type"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("content", "headers", "query", "status", "words"),
    [case[1:] for case in CASES],
    ids=[case[0] for case in CASES],
)
def test_bad_request_gets_its_4xx_and_the_next_succeeds(
    client: TestClient,
    content: bytes,
    headers: dict[str, str],
    query: dict[str, str],
    status: int,
    words: str,
) -> None:
    reply = client.post("/v1/estimate", content=content, headers=headers, params=query)
    assert reply.status_code == status, reply.text
    error = reply.json()
    assert words in error["detail"]
    assert isinstance(error["kind"], str) and error["kind"]
    good = client.post(
        "/v1/estimate", json={"points": GOOD, "max_iterations": 2, "budget_ms": 5000}
    )
    assert good.status_code == 200
    assert good.json()["iterations"] == 2


def test_oversize_chunked_body_is_refused_while_streaming(client: TestClient) -> None:
    """No Content-Length: the body is counted as it arrives."""

    def chunks() -> Iterator[bytes]:
        for _ in range(40):
            yield b"\0" * 12 * 1024

    reply = client.post("/v1/estimate", content=chunks(), headers=BINARY)
    assert reply.status_code == 413
    assert "exceeds the limit" in reply.json()["detail"]


def test_unknown_path_and_method_are_json_errors(client: TestClient) -> None:
    assert client.get("/v1/nothing").json()["kind"] == "not_found"
    reply = client.get("/v1/estimate")
    assert reply.status_code == 405 and reply.json()["kind"] == "method_not_allowed"


numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.integers(-(10**6), 10**6),
    st.just(1e308),
    st.text(max_size=3),
    st.none(),
)
points = st.one_of(
    st.lists(st.lists(numbers, min_size=0, max_size=4), max_size=60),
    st.lists(st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3), min_size=30, max_size=60),
    numbers,
)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    points=points,
    budget=st.one_of(numbers, st.floats(-10, 1e5)),
    model=st.sampled_from([None, "tiny", "x"]),
)
def test_no_request_body_makes_a_500(
    client: TestClient, points: object, budget: object, model: str | None
) -> None:
    request = {"points": points, "budget_ms": budget, "model": model}
    reply = client.post("/v1/estimate", content=json.dumps(request), headers=JSON)
    # a budget too small for one step at that moment (1 ms on a busy machine) is refused as
    # overloaded, with a reason: a 503 the caller may retry, not a server error
    overloaded = reply.status_code == 503 and reply.json()["kind"] == "overloaded"
    assert reply.status_code in (200, 400, 404, 422) or overloaded, reply.text
    if reply.status_code != 200:
        assert reply.json()["detail"]


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(raw=st.binary(max_size=2000))
def test_no_binary_body_makes_a_500(client: TestClient, raw: bytes) -> None:
    reply = client.post("/v1/estimate", content=raw, headers=BINARY, params={"max_iterations": 1})
    assert reply.status_code in (200, 400, 422), reply.text
