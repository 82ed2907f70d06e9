"""The Ray Serve replica: the service's own FastAPI app (``itnet.service.app.create_app``), run
in-process, one per replica.

Each replica loads the models (the app's lifespan, entered at construction) and answers HTTP
requests handed to it by the gateway (``itnet.scale.gateway``) as plain values: the request goes
through the whole app (decoding, limits, the concurrency gate, ``AnytimeRun``, error replies)
exactly as it would under uvicorn, and the reply comes back with an ``X-Itnet-Replica`` header
that names the replica and its process id. WebSocket streams run the app's stream route the same
way, their messages forwarded one at a time (``stream``).
"""

from __future__ import annotations

import asyncio
import json
import os
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import httpx
from ray import serve

REPLICA_HEADER = "x-itnet-replica"
# Set by whoever sends the reply on (Starlette), or meaningless once the body is whole.
HOP_HEADERS = {"content-length", "transfer-encoding", "connection", "keep-alive"}
STREAM_PATH = "/v1/estimate/stream"


@dataclass(frozen=True)
class Forwarded:
    """An HTTP request or reply as plain values (what crosses between Ray actors)."""

    status: int  # 0 for a request
    method: str
    path: str
    query: str
    headers: list[tuple[str, str]]
    body: bytes


@serve.deployment(name="Estimator")
class Estimator:
    """One replica of the service: models loaded once, requests run through the real app."""

    async def __init__(self, settings: dict[str, Any] | None = None) -> None:
        from itnet.service.app import create_app
        from itnet.service.settings import Settings

        self.app = create_app(Settings(**(settings or {})))
        self.name = f"{serve.get_replica_context().replica_id.unique_id}/pid={os.getpid()}"
        self._lifespan = self.app.router.lifespan_context(self.app)
        await self._lifespan.__aenter__()
        state = self.app.state.service
        if not state.ready:  # Serve retries the constructor and reports the deployment failed
            raise RuntimeError(f"no model loaded: {state.load_error}")
        transport = httpx.ASGITransport(app=self.app)
        self.client = httpx.AsyncClient(transport=transport, base_url="http://itnet-replica")

    async def http(self, request: Forwarded) -> Forwarded:
        """Run one HTTP request through the app; the reply, tagged with this replica."""
        reply = await self.client.request(
            request.method,
            request.path,
            params=httpx.QueryParams(request.query),
            headers=[(k, v) for k, v in request.headers if k.lower() not in HOP_HEADERS],
            content=request.body,
        )
        headers = [(k, v) for k, v in reply.headers.multi_items() if k not in HOP_HEADERS]
        headers.append((REPLICA_HEADER, self.name))
        return Forwarded(reply.status_code, "", "", "", headers, reply.content)

    async def stream(self, first_message: str) -> AsyncIterator[str]:
        """Run the app's WebSocket route on ``first_message`` (the request); yield each text
        message it sends, then ``{"type": "close", "code": ..., "replica": ...}``."""
        sent: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        done = asyncio.Event()
        incoming = [
            {"type": "websocket.connect"},
            {"type": "websocket.receive", "text": first_message},
        ]

        async def receive() -> dict[str, Any]:
            if incoming:
                return incoming.pop(0)
            await done.wait()  # the peer says nothing more (a cancel cannot cross the gateway)
            return {"type": "websocket.disconnect", "code": 1000}

        async def send(message: dict[str, Any]) -> None:
            await sent.put(message)

        scope = {"type": "websocket", "path": STREAM_PATH, "raw_path": STREAM_PATH.encode(),
                 "query_string": b"", "headers": [], "scheme": "ws", "subprotocols": [],
                 "server": ("itnet-replica", 80), "client": ("gateway", 0),
                 "asgi": {"version": "3.0"}, "app": self.app}  # fmt: skip
        task = asyncio.create_task(self.app(scope, receive, send))
        code = 1006
        try:
            while True:
                getter = asyncio.create_task(sent.get())
                await asyncio.wait({getter, task}, return_when=asyncio.FIRST_COMPLETED)
                if not getter.done():
                    getter.cancel()
                    break  # the route returned without closing
                message = getter.result()
                if message["type"] == "websocket.send" and message.get("text") is not None:
                    yield message["text"]
                elif message["type"] == "websocket.close":
                    code = int(message.get("code", 1000))
                    break
        finally:
            done.set()
            await task
        yield json.dumps({"type": "close", "code": code, "replica": self.name})

    def check_health(self) -> None:
        """Serve's periodic health check: the models are still loaded."""
        if not self.app.state.service.ready:
            raise RuntimeError("no model loaded")

    async def __del__(self) -> None:
        await self.client.aclose()
        await self._lifespan.__aexit__(None, None, None)
