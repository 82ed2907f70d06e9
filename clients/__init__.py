"""Python clients of the itnet service (``pip install itnet``; no torch, no service code).

``ItnetClient`` (blocking) and ``AsyncItnetClient`` (asyncio) call ``POST /v1/estimate`` (JSON or
a binary float32 body) and ``WS /v1/estimate/stream`` (an iterator of per-iteration estimates,
cancellable), and ``POST /v1/scene`` (every object of a depth image or a scene cloud). What to
ask is a ``PoseRequest`` (the service's own declaration of a request), or
its fields by name. Poses are T_canonical_from_input, 4x4, in the cloud's own units.
"""

from itnet.clients.async_client import AsyncEstimateStream, AsyncItnetClient
from itnet.clients.sync_client import EstimateStream, ItnetClient
from itnet.clients.wire import (
    Estimate,
    EstimateResult,
    ItnetClientError,
    ItnetConnectionError,
    ItnetRequestError,
)
from itnet.pose.request import PoseRequest

__all__ = [
    "AsyncEstimateStream",
    "AsyncItnetClient",
    "Estimate",
    "EstimateResult",
    "EstimateStream",
    "ItnetClient",
    "ItnetClientError",
    "ItnetConnectionError",
    "ItnetRequestError",
    "PoseRequest",
]
