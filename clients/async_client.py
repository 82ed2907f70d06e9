"""asyncio client of the itnet service, the same calls as ``ItnetClient`` awaited.

async with AsyncItnetClient("http://127.0.0.1:8000") as client:
    result = await client.estimate(points, budget_ms=50)
    async with await client.stream(points, budget_ms=200) as stream:
        async for estimate in stream:
            ...
            await stream.cancel()
    stream.result
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import httpx
from numpy.typing import ArrayLike
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from itnet.clients.wire import (
    BINARY,
    ESTIMATE_PATH,
    SCENE_PATH,
    Estimate,
    EstimateResult,
    ItnetClientError,
    ItnetConnectionError,
    binary_body,
    json_request,
    parse_message,
    pose_request,
    reply_json,
    request_fields,
    scene_request,
    websocket_url,
)
from itnet.pose.request import PoseRequest

if TYPE_CHECKING:
    from itnet.scene.request import SceneRequest


class AsyncEstimateStream(AsyncIterator[Estimate]):
    """The estimates of one streamed request; ``result`` once the final message came."""

    def __init__(self, connection: ClientConnection, timeout: float) -> None:
        self._ws, self._timeout = connection, timeout
        self.estimates: list[Estimate] = []
        self.result: EstimateResult | None = None

    def __aiter__(self) -> AsyncEstimateStream:
        return self

    async def __anext__(self) -> Estimate:
        while self.result is None:
            kind, message = await self._receive()
            if kind == "estimate":
                self.estimates.append(Estimate.from_dict(message))
                return self.estimates[-1]
            if kind == "result":
                self.result = EstimateResult.from_dict(message, self.estimates)
                await self.close()
        raise StopAsyncIteration

    async def _receive(self) -> tuple[str, dict[str, Any]]:
        try:
            return parse_message(await asyncio.wait_for(self._ws.recv(), self._timeout))
        except TimeoutError:
            await self.close()
            raise ItnetConnectionError(f"no stream message within {self._timeout} s") from None
        except ConnectionClosed as err:
            raise ItnetConnectionError(f"the stream closed before the result ({err})") from None
        except ItnetClientError:
            await self.close()
            raise

    async def cancel(self) -> None:
        """Ask the server to stop; iteration goes on until its final message (the best so far)."""
        with contextlib.suppress(ConnectionClosed):
            await self._ws.send(json.dumps({"type": "cancel"}))

    async def run_to_end(self) -> EstimateResult:
        """Consume the remaining estimates; the final result."""
        async for _ in self:
            pass
        assert self.result is not None
        return self.result

    async def close(self) -> None:
        await self._ws.close()

    async def __aenter__(self) -> AsyncEstimateStream:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


class AsyncItnetClient:
    """HTTP and WebSocket client for one itnet service, for asyncio code."""

    def __init__(self, base_url: str, timeout: float = 30.0) -> None:
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self._http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout)

    async def estimate(
        self,
        points: ArrayLike,
        request: PoseRequest | None = None,
        binary: bool = False,
        **fields: Any,
    ) -> EstimateResult:
        """POST one cloud (N, 3) -> its EstimateResult (see ``ItnetClient.estimate``)."""
        sent = pose_request(request, fields)
        try:
            if binary:
                reply = await self._http.post(
                    ESTIMATE_PATH,
                    content=binary_body(points),
                    params=sent.to_query(),
                    headers=BINARY,
                )
            else:
                reply = await self._http.post(
                    ESTIMATE_PATH, json=json_request(points, request_fields(sent))
                )
        except httpx.TransportError as err:
            raise ItnetConnectionError(f"{self.base_url}: {err}") from None
        return EstimateResult.from_dict(_json(reply))

    async def stream(
        self,
        points: ArrayLike,
        request: PoseRequest | None = None,
        **fields: Any,
    ) -> AsyncEstimateStream:
        """Open the WebSocket and send the request; iterate the returned stream for estimates."""
        request = json_request(
            points,
            request_fields(pose_request(request, fields)),
        )
        try:
            url = websocket_url(self.base_url)
            connection = await connect(url, open_timeout=self.timeout, max_size=None)
        except (OSError, InvalidHandshake, InvalidURI, TimeoutError) as err:
            raise ItnetConnectionError(f"{self.base_url}: cannot open the stream ({err})") from None
        await connection.send(json.dumps(request))
        return AsyncEstimateStream(connection, self.timeout)

    async def scene(
        self,
        scene: ArrayLike | bytes | str | Path,
        intrinsics: tuple[float, float, float, float] | None = None,
        request: SceneRequest | None = None,
        indices: bool = True,
        **fields: Any,
    ) -> Any:
        """``POST /v1/scene`` -> the reply (see ``ItnetClient.scene``)."""
        body, query, headers = scene_request(scene, intrinsics, request, indices, fields)
        try:
            reply = await self._http.post(SCENE_PATH, content=body, params=query, headers=headers)
        except httpx.TransportError as err:
            raise ItnetConnectionError(f"{self.base_url}: {err}") from None
        return _json(reply)

    async def models(self) -> Any:
        """``GET /v1/models``: what the service has loaded."""
        return await self._get("/v1/models")

    async def health(self) -> Any:
        """``GET /healthz``."""
        return await self._get("/healthz")

    async def _get(self, path: str) -> Any:
        try:
            return _json(await self._http.get(path))
        except httpx.TransportError as err:
            raise ItnetConnectionError(f"{self.base_url}: {err}") from None

    async def close(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> AsyncItnetClient:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()


def _json(reply: httpx.Response) -> Any:
    return reply_json(reply.status_code, reply.text)
