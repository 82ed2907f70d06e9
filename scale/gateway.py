"""The Ray Serve ingress: the service's HTTP API, forwarded to the ``Estimator`` replicas.

Every path and method goes to a replica as it came (``itnet.scale.replica`` runs it through the
service's own app), so the API, its errors and its limits are the service's. What the gateway
adds is what one process cannot do for itself: when the replica running a request dies (its
process killed, its node lost), the request goes to another replica (estimates have no side
effects, so running one again is safe), at most ``attempts`` times; if none can take it, the reply
is a 503 with ``Retry-After`` (kind ``unavailable``), the one reply a client should retry. A
reply that needed more than one attempt says so in ``X-Itnet-Attempts``.

The gateway reads at most ``max_body_bytes`` + 1 bytes of a body before handing it on: the
replica's app then refuses a larger one with its usual 413, and the gateway never holds more.
"""

from __future__ import annotations

import json
import logging
from typing import Any

from ray import serve
from ray.exceptions import RayActorError
from ray.serve.exceptions import BackPressureError, DeploymentUnavailableError
from ray.serve.handle import DeploymentHandle
from starlette.applications import Starlette
from starlette.requests import ClientDisconnect, Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from itnet.scale.replica import STREAM_PATH, Forwarded

log = logging.getLogger("itnet.scale")
METHODS = ["GET", "POST", "PUT", "PATCH", "DELETE", "HEAD", "OPTIONS"]
ATTEMPTS_HEADER = "x-itnet-attempts"


def unavailable(detail: str, retry_after_s: int) -> JSONResponse:
    """The service's error shape; the reply that tells a client to retry."""
    return JSONResponse(
        {"detail": detail, "kind": "unavailable"},
        status_code=503,
        headers={"Retry-After": str(retry_after_s)},
    )


async def capped_body(request: Request, cap: int) -> bytes:
    """The body, or its first ``cap`` bytes (the replica refuses it on its length anyway)."""
    chunks, size = [], 0
    try:
        async for chunk in request.stream():
            chunks.append(chunk)
            size += len(chunk)
            if size >= cap:
                break
    except ClientDisconnect:
        pass
    return b"".join(chunks)[:cap]


def build_gateway_app(
    estimator: DeploymentHandle, attempts: int, max_body_bytes: int, retry_after_s: int
) -> Starlette:
    """A catch-all HTTP route and the stream route, both handing the work to ``estimator``."""

    async def forward(request: Request) -> Response:
        body = await capped_body(request, max_body_bytes + 1)
        message = Forwarded(0, request.method, request.url.path, request.url.query,
                            list(request.headers.items()), body)  # fmt: skip
        lost: list[str] = []
        for attempt in range(1, attempts + 1):
            try:
                reply: Forwarded = await estimator.http.remote(message)
            except RayActorError as err:  # the replica died under the request: try another
                lost.append(type(err).__name__)
                log.warning("attempt %d of %s %s: replica lost (%s)", attempt,
                            request.method, request.url.path, type(err).__name__)  # fmt: skip
                continue
            except (BackPressureError, DeploymentUnavailableError) as err:
                return unavailable(f"no replica can take the request now ({err})", retry_after_s)
            headers = dict(reply.headers)
            if attempt > 1:
                headers[ATTEMPTS_HEADER] = str(attempt)
            return Response(reply.body, status_code=reply.status, headers=headers)
        return unavailable(
            f"the replica serving the request was lost {len(lost)} times "
            f"({', '.join(lost)}); retry in {retry_after_s} s",
            retry_after_s,
        )

    async def stream(websocket: WebSocket) -> None:
        await websocket.accept()
        try:
            first = await websocket.receive_text()
        except (WebSocketDisconnect, KeyError):
            return
        code = 1011
        try:
            async for text in estimator.options(stream=True).stream.remote(first):
                message: dict[str, Any] = json.loads(text)
                if message.get("type") == "close":
                    code = int(message["code"])
                    break
                await websocket.send_text(text)
        except RayActorError:
            await websocket.send_text(json.dumps({"type": "error", "kind": "unavailable",
                                                  "detail": "the replica serving the stream "
                                                  "was lost; retry"}))  # fmt: skip
            code = 1013  # try again later
        except WebSocketDisconnect:
            return
        await websocket.close(code)

    return Starlette(
        routes=[
            WebSocketRoute(STREAM_PATH, stream),
            Route("/{path:path}", forward, methods=METHODS),
        ]
    )


@serve.deployment(name="Gateway", ray_actor_options={"num_cpus": 0})
@serve.ingress()
class Gateway:
    """The HTTP entry point of the Serve application (see the module docstring)."""

    def __init__(
        self,
        estimator: DeploymentHandle,
        attempts: int = 3,
        max_body_bytes: int = 16 * 2**20,
        retry_after_s: int = 1,
    ) -> None:
        self.estimator = estimator
        self.options = (attempts, max_body_bytes, retry_after_s)

    def __serve_build_asgi_app__(self) -> Starlette:
        return build_gateway_app(self.estimator, *self.options)
