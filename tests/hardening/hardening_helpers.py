"""Helpers of the hardening tests: a real uvicorn server (in a thread of the test process, on a
loopback socket, with the service's connection limits), small limits, a test cloud, polling."""

from __future__ import annotations

import os
import socket
import struct
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import uvicorn
from fastapi import FastAPI
from numpy.typing import NDArray

from itnet.model_card import METADATA_KEY
from itnet.pose.runtime import LoadedModel
from itnet.service.app import create_app
from itnet.service.server import serving_in_thread
from itnet.service.settings import LimitSettings, ServerSettings, Settings
from itnet.service.state import ServiceState

# Small limits and short timeouts, so that each can be crossed in well under a second.
LIMITS = LimitSettings(
    max_points=4096,
    max_budget_ms=5000,
    max_iterations=100,
    max_body_bytes=64 * 1024,
    max_ws_message_bytes=64 * 1024,
    max_concurrent_requests=4,
    ws_request_timeout_s=1.0,
    ws_send_timeout_s=0.5,
    body_timeout_s=0.5,
    max_buffered_bytes=512 * 1024,
)
SERVER = ServerSettings(
    max_connections=32,
    probe_connections=4,
    ws_buffer_bytes=256 * 1024,
    keep_alive_s=1,
    header_timeout_s=0.5,
    max_header_bytes=4096,
    graceful_shutdown_s=5,
)


@dataclass
class LiveServer:
    url: str
    app: FastAPI
    server: uvicorn.Server

    @property
    def host_port(self) -> tuple[str, int]:
        host, port = self.url.removeprefix("http://").split(":")
        return host, int(port)

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://") + "/v1/estimate/stream"

    @property
    def state(self) -> ServiceState:
        return self.app.state.service  # type: ignore[no-any-return]


@contextmanager
def live_server(settings: Settings, models: dict[str, LoadedModel]) -> Iterator[LiveServer]:
    """uvicorn serving ``create_app(settings, models)`` on a loopback socket in a thread."""
    app = create_app(settings, models)
    with serving_in_thread(app, settings) as (url, server):
        yield LiveServer(url, app, server)


def cloud(n: int = 300, seed: int = 0) -> NDArray[np.float32]:
    rng = np.random.default_rng(seed)
    return (rng.uniform(-1, 1, size=(n, 3)) * [0.3, 0.5, 0.2] + [1.0, -2.0, 3.0]).astype(np.float32)


def wait_for(condition: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    """Poll ``condition`` until it holds (True) or ``timeout_s`` passes (False)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def with_card(source: Path, target: Path, card: str | None) -> None:
    """Copy an ONNX model, replacing its model card JSON (None: removing the card)."""
    import onnx

    model = onnx.load(str(source))
    kept = [p for p in model.metadata_props if p.key != METADATA_KEY]
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    if card is not None:
        model.metadata_props.add(key=METADATA_KEY, value=card)
    onnx.save(model, str(target))


def scaled(examples: int) -> int:
    """A fuzz test's example count times ``ITNET_FUZZ_SCALE`` (default 1; e.g. 30 for a long run)."""
    return max(1, round(examples * float(os.environ.get("ITNET_FUZZ_SCALE", "1"))))


def ws_handshake(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    sock.sendall(
        b"GET /v1/estimate/stream HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n"
        b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
        b"Sec-WebSocket-Version: 13\r\n\r\n"
    )
    reply = sock.recv(4096)
    assert reply.startswith(b"HTTP/1.1 101"), reply[:100]
    return sock


def masked_frame_head(length: int, opcode: int = 0x1) -> bytes:
    """A client frame header (FIN, ``opcode``) announcing ``length`` payload bytes, zero mask."""
    if length < 126:
        return bytes([0x80 | opcode, 0x80 | length]) + b"\0\0\0\0"
    return bytes([0x80 | opcode, 0x80 | 126]) + struct.pack("!H", length) + b"\0\0\0\0"
