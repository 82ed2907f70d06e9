"""Bodies that are legal in size but hostile in content: the ``Decoder``, strict coordinates
and the cut names."""

from __future__ import annotations

import gzip
import json
import logging
import time
import tracemalloc
from collections.abc import Iterator
from contextlib import suppress

import httpx
import pytest
from fastapi.testclient import TestClient
from hardening_helpers import LIMITS, LiveServer, masked_frame_head, ws_handshake

from itnet.pose.runtime import LoadedModel
from itnet.service.app import create_app
from itnet.service.errors import ServiceError
from itnet.service.settings import Settings


@pytest.fixture(scope="module")
def client(settings: Settings, tiny: LoadedModel) -> Iterator[TestClient]:
    with TestClient(create_app(settings, {"tiny": tiny})) as http:
        yield http


def refused(reply: httpx.Response, status: int, kind: str) -> str:
    assert reply.status_code == status, reply.text[:300]
    assert reply.json()["kind"] == kind
    return str(reply.json()["detail"])


@pytest.mark.parametrize("bad", [True, "1.5", None])
def test_booleans_and_strings_are_not_coordinates(client: TestClient, points: list, bad) -> None:
    cloud = [list(p) for p in points]
    cloud[5][1] = bad
    refused(client.post("/v1/estimate", json={"points": cloud}), 422, "invalid_request")


def test_integers_are_coordinates(client: TestClient, points: list) -> None:
    cloud = [[round(x * 10) for x in p] for p in points]
    assert (
        client.post("/v1/estimate", json={"points": cloud, "max_iterations": 1}).status_code == 200
    )


def test_query_parameters_beside_a_json_body_are_refused(client: TestClient, points: list) -> None:
    detail = refused(
        client.post("/v1/estimate?budget_ms=5", json={"points": points}), 422, "invalid_request"
    )
    assert "budget_ms" in detail and "binary" in detail


def test_a_long_model_or_field_name_is_not_echoed_whole(client: TestClient, points: list) -> None:
    name, few = "m" * 40_000, points[:40]  # (the tests' body limit is 64 KiB)
    detail = refused(client.post("/v1/estimate", json={"points": few, "model": name}), 404,
                     "unknown_model")  # fmt: skip
    assert len(detail) < 300 and "40000 characters" in detail
    detail = refused(client.post("/v1/estimate", json={"points": few, name: 1}), 422,
                     "invalid_request")  # fmt: skip
    assert len(detail) < 300


def test_a_cloud_scaled_by_1e200_is_out_of_range(client: TestClient, points: list) -> None:
    cloud = [[x * 1e200 for x in p] for p in points]
    detail = refused(client.post("/v1/estimate", json={"points": cloud}), 422, "bad_cloud")
    assert "out of range" in detail and "degenerate" not in detail


def test_a_compressed_body_is_refused_with_415(client: TestClient, points: list) -> None:
    body = gzip.compress(json.dumps({"points": points}).encode())
    reply = client.post("/v1/estimate", content=body,
                        headers={"content-type": "application/json", "content-encoding": "gzip"})  # fmt: skip
    assert "gzip" in refused(reply, 415, "unsupported_media_type")


def test_too_many_points_are_refused_without_parsing_them() -> None:
    """Ten times max_points as JSON: refused from its brackets, in a fraction of a parse's time
    and memory (before: parsed whole into Python lists, then refused)."""
    from itnet.service.decode import Decoder

    limit = 20_000
    body = json.dumps({"points": [[0.1, 0.2, 0.3]] * (10 * limit)}).encode()
    decoder = Decoder(max_points=limit, heavy_bytes=len(body) * 2, lanes=1, retry_after_s=1)
    start = time.perf_counter()
    json.loads(body)  # what parsing it would cost, on this machine at this moment
    parse_seconds = time.perf_counter() - start
    tracemalloc.start()
    start = time.perf_counter()
    with pytest.raises(ServiceError) as err:
        decoder.json(body)
    seconds = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert err.value.status == 422 and "before parsing" in err.value.detail
    assert peak < len(body) / 10 and seconds < parse_seconds / 5, (seconds, parse_seconds)


def test_large_json_bodies_are_parsed_one_at_a_time(points: list) -> None:
    from itnet.service.decode import Decoder

    body = json.dumps({"points": points}).encode()
    decoder = Decoder(max_points=LIMITS.max_points, heavy_bytes=len(body), lanes=1,
                      retry_after_s=1)  # fmt: skip
    with decoder.lane(), pytest.raises(ServiceError) as err:  # one is being parsed
        decoder.json(body)
    assert err.value.status == 503 and err.value.headers["Retry-After"] == "1"
    cloud, _ = decoder.json(body)  # the lane is free again
    assert cloud.shape == (len(points), 3)


def test_invalid_utf8_on_the_websocket_closes_1007_without_a_traceback(
    slow_server: LiveServer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    payload = b'{"points": "\xff\xfe"}'
    for _ in range(3):
        sock = ws_handshake(slow_server.host_port[1])
        sock.sendall(masked_frame_head(len(payload)) + payload)
        sock.settimeout(5)
        frame = sock.recv(64)
        sock.close()
        assert frame[:1] == b"\x88" and frame[2:4] == (1007).to_bytes(2, "big"), frame
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"
    assert httpx.get(f"{slow_server.url}/healthz").status_code == 200


def test_frames_sent_before_the_handshake_reply_close_without_a_traceback(
    slow_server: LiveServer, caplog: pytest.LogCaptureFixture
) -> None:
    """A client that sends a frame with its upgrade request, before the 101 (RFC 6455 forbids
    it): the connection is closed with one log line (before: uvicorn's AssertionError and a
    'Fatal error on transport' traceback per connection)."""
    import socket

    caplog.set_level(logging.INFO)
    head = (b"GET /v1/estimate/stream HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n"
            b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
            b"Sec-WebSocket-Version: 13\r\n\r\n")  # fmt: skip
    for _ in range(3):
        sock = socket.create_connection(slow_server.host_port, timeout=5)
        # more than one read of the server's: uvicorn's upgrade then sees the frame mid-payload
        size = 1024 * 1024
        with suppress(ConnectionError):  # closed (perhaps reset) by the server, not timed out
            sock.sendall(head + b"\x81\xff" + size.to_bytes(8, "big") + b"\0" * 4 + b" " * size)
            while sock.recv(65536):
                pass
        sock.close()
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"
    assert httpx.get(f"{slow_server.url}/healthz").status_code == 200
