"""Faulty clients on a real server: they disconnect mid-run, stop reading, cancel in storms. The
server stops their work, frees their slots, and keeps serving."""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from typing import Any

import httpx
import pytest
from hardening_helpers import LiveServer, wait_for
from prometheus_client.parser import text_string_to_metric_families
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect


def metric(server: LiveServer, name: str, **labels: str) -> float:
    text = httpx.get(f"{server.url}/metrics").text
    return sum(
        s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
        if s.name == name and labels.items() <= s.labels.items()
    )


def server_errors(server: LiveServer) -> float:
    text = httpx.get(f"{server.url}/metrics").text
    return sum(
        s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
        if s.name == "itnet_requests_total" and s.labels["status"] in ("500", "ws_1011")
    )


def assert_healthy(server: LiveServer, points: list) -> None:
    """No slot held, nothing in flight, no 5xx ever, and a good request gets its answer."""
    assert wait_for(lambda: server.state.gate.active == 0), "a slot was never released"
    assert metric(server, "itnet_in_flight") == 0
    assert server_errors(server) == 0
    request = {"points": points, "budget_ms": 2000, "max_iterations": 2}
    reply = httpx.post(f"{server.url}/v1/estimate", json=request)
    assert reply.status_code == 200 and reply.json()["iterations"] == 2


def long_request(points: list) -> dict[str, Any]:
    return {"points": points, "budget_ms": 4000, "max_iterations": 100}


def test_an_http_client_that_disconnects_stops_its_run(
    slow_server: LiveServer, slow: Any, points: list
) -> None:
    with pytest.raises(httpx.ReadTimeout):
        httpx.post(f"{slow_server.url}/v1/estimate", json=long_request(points), timeout=0.15)
    left_at = slow.steps
    assert wait_for(lambda: slow_server.state.gate.active == 0, 1.0)
    ended_at = slow.steps
    time.sleep(0.1)  # five more steps' worth, had it gone on
    assert slow.steps == ended_at  # nothing runs once the request is over
    # The step running when the client left, and at most one more that started before the
    # event loop heard of the disconnect (20 ms steps; on a loaded machine that can take longer).
    assert slow.steps - left_at <= 2
    assert metric(slow_server, "itnet_runs_total", stopped_by="disconnected") == 1
    assert_healthy(slow_server, points)


def test_a_stream_client_that_vanishes_stops_its_run(
    slow_server: LiveServer, slow: Any, points: list
) -> None:
    """The TCP connection drops without a close frame (a crashed client)."""
    ws = connect(slow_server.ws_url, open_timeout=5)
    ws.send(json.dumps(long_request(points)))
    assert json.loads(ws.recv(timeout=5))["iteration"] == 1
    ws.socket.shutdown(socket.SHUT_RDWR)
    ws.socket.close()
    left_at = slow.steps
    assert wait_for(lambda: slow_server.state.gate.active == 0, 1.0)
    ended_at = slow.steps
    time.sleep(0.1)
    assert slow.steps == ended_at  # nothing runs once the stream is over
    assert slow.steps - left_at <= 2  # as for HTTP above
    assert metric(slow_server, "itnet_runs_total", stopped_by="disconnected") == 1
    assert_healthy(slow_server, points)


def test_a_client_that_leaves_while_sending_its_body_is_no_server_error(
    slow_server: LiveServer, points: list
) -> None:
    """Regression: starlette's ClientDisconnect escaped the body reader as a 500."""
    head = (b"POST /v1/estimate HTTP/1.1\r\nHost: x\r\ncontent-type: application/json\r\n"
            b"content-length: 1000\r\n\r\n")  # fmt: skip
    sock = socket.create_connection(slow_server.host_port, timeout=5)
    sock.sendall(head + b'{"points": [[1, 2, 3], ')
    time.sleep(0.05)
    sock.close()
    status = {"endpoint": "/v1/estimate", "status": "499"}
    assert wait_for(lambda: metric(slow_server, "itnet_requests_total", **status) == 1)
    assert_healthy(slow_server, points)


def test_a_slow_reader_still_gets_every_message(slow_server: LiveServer, points: list) -> None:
    """A client that reads nothing for a second, then everything: the server buffered it all and
    ended the run on time; nothing was lost."""
    with connect(slow_server.ws_url, open_timeout=5) as ws:
        ws.send(json.dumps({"points": points, "budget_ms": 3000, "max_iterations": 15}))
        time.sleep(1.0)
        messages = [json.loads(ws.recv(timeout=5)) for _ in range(16)]
        with pytest.raises(ConnectionClosed):
            ws.recv(timeout=5)
    assert [m["type"] for m in messages] == ["estimate"] * 15 + ["result"]
    assert messages[-1]["iterations"] == 15 and ws.close_code == 1000
    assert_healthy(slow_server, points)


def storm_client(url: str, request: str, index: int, outcomes: dict[int, str]) -> None:
    """One of the storm's clients: cancels at once (index % 3 == 0), leaves at once (1), or drops
    its connection after the first estimate (2)."""
    try:
        ws: ClientConnection = connect(url, open_timeout=10)
        ws.send(request)
        if index % 3 == 0:
            # A request refused at once (all slots busy) is answered and closed before the
            # cancel goes out: the answer is still there to read.
            with contextlib.suppress(ConnectionClosed):
                ws.send('{"type": "cancel"}')
            while (message := json.loads(ws.recv(timeout=10)))["type"] == "estimate":
                pass
            outcomes[index] = message.get("stopped_by") or message["kind"]
            ws.close()
        elif index % 3 == 1:
            ws.close()
            outcomes[index] = "left"
        else:
            ws.recv(timeout=10)
            ws.socket.close()
            outcomes[index] = "dropped"
    except (ConnectionClosed, TimeoutError, OSError) as err:
        outcomes[index] = type(err).__name__


def impatient_client(url: str, request: str, index: int, outcomes: dict[int, str]) -> None:
    """Gives up on its POST after 50 ms."""
    try:
        reply = httpx.post(f"{url}/v1/estimate", content=request, timeout=0.05,
                           headers={"content-type": "application/json"})  # fmt: skip
        outcomes[index] = str(reply.status_code)
    except httpx.TimeoutException:
        outcomes[index] = "timed out"


def test_a_cancel_storm_leaves_the_server_healthy(slow_server: LiveServer, points: list) -> None:
    """30 stream clients that cancel, leave or drop, and 20 HTTP clients that time out, all at
    once against 4 slots."""
    request = json.dumps(long_request(points))
    outcomes: dict[int, str] = {}
    threads = [
        threading.Thread(target=storm_client, args=(slow_server.ws_url, request, i, outcomes))
        for i in range(30)
    ] + [
        threading.Thread(target=impatient_client, args=(slow_server.url, request, i, outcomes))
        for i in range(30, 50)
    ]
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=20)
    assert time.perf_counter() - start < 10
    assert len(outcomes) == 50, outcomes
    cancelling = {outcomes[i] for i in range(0, 30, 3)}
    # A cancel is answered with the best estimate so far, or refused while all slots are busy.
    assert cancelling <= {"cancelled", "overloaded"} and "cancelled" in cancelling, outcomes
    assert {outcomes[i] for i in range(30, 50)} <= {"timed out", "503"}, outcomes
    assert_healthy(slow_server, points)
