"""Blocking client of the itnet service: ``POST /v1/estimate``, ``WS /v1/estimate/stream`` and
``POST /v1/scene`` and ``POST /v1/align``.

with ItnetClient("http://127.0.0.1:8000") as client:
    result = client.estimate(points, budget_ms=50)          # EstimateResult
    with client.stream(points, budget_ms=200) as stream:
        for estimate in stream:                             # one per iteration, as it comes
            if estimate.update_rotation_deg < 0.1:
                stream.cancel()                             # the server answers with the result
    stream.result                                           # EstimateResult
    reply = client.scene("frame.png", intrinsics=(525, 525, 319.5, 239.5))  # every object
    aligned = client.align(a, b, budget_ms=100)             # T_b_from_a, its probability
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import httpx
from numpy.typing import ArrayLike
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
from websockets.sync.client import ClientConnection, connect

from itnet.alignment.request import AlignRequest
from itnet.clients.wire import (
    ALIGN_PATH,
    BINARY,
    ESTIMATE_PATH,
    SCENE_PATH,
    Estimate,
    EstimateResult,
    ItnetClientError,
    ItnetConnectionError,
    align_request,
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


class EstimateStream(Iterator[Estimate]):
    """The estimates of one streamed request, in order; ``result`` once the final message came."""

    def __init__(self, connection: ClientConnection, timeout: float) -> None:
        self._ws, self._timeout = connection, timeout
        self.estimates: list[Estimate] = []
        self.result: EstimateResult | None = None

    def __next__(self) -> Estimate:
        while self.result is None:
            kind, message = self._receive()
            if kind == "estimate":
                self.estimates.append(Estimate.from_dict(message))
                return self.estimates[-1]
            if kind == "result":
                self.result = EstimateResult.from_dict(message, self.estimates)
                self.close()
            # any other message type is one this client does not know: skip it
        raise StopIteration

    def _receive(self) -> tuple[str, dict[str, Any]]:
        try:
            return parse_message(self._ws.recv(timeout=self._timeout))
        except TimeoutError:
            self.close()
            raise ItnetConnectionError(f"no stream message within {self._timeout} s") from None
        except ConnectionClosed as err:
            raise ItnetConnectionError(f"the stream closed before the result ({err})") from None
        except ItnetClientError:
            self.close()
            raise

    def cancel(self) -> None:
        """Ask the server to stop; iteration goes on until its final message (the best so far)."""
        with contextlib.suppress(ConnectionClosed):
            self._ws.send(json.dumps({"type": "cancel"}))

    def run_to_end(self) -> EstimateResult:
        """Consume the remaining estimates; the final result."""
        for _ in self:
            pass
        assert self.result is not None
        return self.result

    def close(self) -> None:
        """Leave (a server stops the work of a client that leaves)."""
        self._ws.close()

    def __enter__(self) -> EstimateStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ItnetClient:
    """HTTP and WebSocket client for one itnet service (``base_url`` like http://host:8000)."""

    def __init__(self, base_url: str, timeout: float = 30.0) -> None:
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout)

    def estimate(
        self,
        points: ArrayLike,
        request: PoseRequest | None = None,
        binary: bool = False,
        **fields: Any,
    ) -> EstimateResult:
        """POST one cloud (N, 3) -> its EstimateResult. ``request`` (a PoseRequest) and
        ``fields`` (any of its fields by name: ``budget_ms=20, model="auto", up=[0, -1, 0]``,
        set on top of it) say what to ask; ``binary`` sends float32 (12 bytes a point) instead
        of JSON. The result's ``ensemble``, ``verified`` and ``rechecked`` say what ran. Raises
        ItnetRequestError (refused), ItnetConnectionError, TypeError for an unknown field."""
        sent = pose_request(request, fields)
        try:
            if binary:
                reply = self._http.post(
                    ESTIMATE_PATH,
                    content=binary_body(points),
                    params=sent.to_query(),
                    headers=BINARY,
                )
            else:
                reply = self._http.post(
                    ESTIMATE_PATH, json=json_request(points, request_fields(sent))
                )
        except httpx.TransportError as err:
            raise ItnetConnectionError(f"{self.base_url}: {err}") from None
        return EstimateResult.from_dict(_json(reply))

    def stream(
        self,
        points: ArrayLike,
        request: PoseRequest | None = None,
        **fields: Any,
    ) -> EstimateStream:
        """Open the WebSocket and send the request; iterate the returned stream for estimates."""
        request = json_request(
            points,
            request_fields(pose_request(request, fields)),
        )
        try:
            url = websocket_url(self.base_url)
            # Entered as a context manager (websockets >= 17.1 warns about a bare connect(); a
            # later release's bare connect() reconnects), left by EstimateStream's close().
            connection = connect(url, open_timeout=self.timeout, max_size=None).__enter__()
        except (OSError, InvalidHandshake, InvalidURI, TimeoutError) as err:
            raise ItnetConnectionError(f"{self.base_url}: cannot open the stream ({err})") from None
        connection.send(json.dumps(request))
        return EstimateStream(connection, self.timeout)

    def scene(
        self,
        scene: ArrayLike | bytes | str | Path,
        intrinsics: tuple[float, float, float, float] | None = None,
        request: SceneRequest | None = None,
        indices: bool = True,
        **fields: Any,
    ) -> Any:
        """``POST /v1/scene``: every object of a depth image or a scene cloud -> the reply (a
        dict: ``objects``, each with ``category``, ``T_canonical_from_input``, ``box``, ...;
        ``up``, ``floor``, ``walls``; docs/scenes.md). ``scene``: a ``.png`` (16-bit, depth
        units) or ``.npy`` file, PNG bytes, a depth image (H, W) (float: metres) or a cloud
        (N, 3) in the camera's frame (metres); ``intrinsics`` (fx, fy, cx, cy) for an image.
        ``request`` (a SceneRequest) and ``fields`` (any of its fields by name: ``budget_ms``,
        ``depth_scale``, ``up``, the finishing switches, ...) say how; ``indices``: each
        object's point indices in the reply. Raises TypeError for an unknown field,
        ItnetRequestError (refused), ItnetConnectionError."""
        body, query, headers = scene_request(scene, intrinsics, request, indices, fields)
        try:
            reply = self._http.post(SCENE_PATH, content=body, params=query, headers=headers)
        except httpx.TransportError as err:
            raise ItnetConnectionError(f"{self.base_url}: {err}") from None
        return _json(reply)

    def align(self, points_a: ArrayLike, points_b: ArrayLike,
              request: AlignRequest | None = None, **fields: Any) -> Any:  # fmt: skip
        """``POST /v1/align``: T_b_from_a, the transform that moves cloud A (N, 3) onto cloud B
        (M, 3) -> the reply (a dict: ``T_b_from_a``, ``hypothesis``, ``probability``,
        ``runner_up``, both poses; docs/align.md). ``request`` (an AlignRequest) and ``fields``
        (any of its fields by name: ``budget_ms=100, up_a=[0, -1, 0]``) say what to ask. Raises
        ItnetRequestError (refused), ItnetConnectionError, ValueError for a field it refuses."""
        sent = align_request(request, fields)
        try:
            reply = self._http.post(ALIGN_PATH, json=sent.body(points_a, points_b))
        except httpx.TransportError as err:
            raise ItnetConnectionError(f"{self.base_url}: {err}") from None
        return _json(reply)

    def models(self) -> Any:
        """``GET /v1/models``: what the service has loaded."""
        return self._get("/v1/models")

    def health(self) -> Any:
        """``GET /healthz``."""
        return self._get("/healthz")

    def _get(self, path: str) -> Any:
        try:
            return _json(self._http.get(path))
        except httpx.TransportError as err:
            raise ItnetConnectionError(f"{self.base_url}: {err}") from None

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> ItnetClient:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _json(reply: httpx.Response) -> Any:
    return reply_json(reply.status_code, reply.text)
