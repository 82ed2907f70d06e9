"""Reading one HTTP request body under the server's limits, before any of it is buffered:

* ``Content-Encoding`` other than ``identity``: 415 at once (compressed bodies are refused, not
  inflated: a few KiB of gzip can expand to gigabytes, and a cloud compresses poorly anyway);
* a ``Content-Length`` over ``max_body_bytes``: 413 at once;
* the bytes it needs not in the server's budget (``max_buffered_bytes``, shared by every request):
  503 + ``Retry-After`` at once, from the ``Content-Length``, or while a body without one arrives;
* the whole body not in by ``body_timeout_s`` after the request's first byte (a deadline, not an
  idle timer: a byte now and then does not extend it): 408.

The bytes stay taken from the budget until the request is done with them.
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import anyio
from starlette.requests import ClientDisconnect, Request

from itnet.service.errors import ServiceError, too_large
from itnet.service.guards.byte_budget import ByteBudget
from itnet.service.settings import LimitSettings


@asynccontextmanager
async def limited_body(
    request: Request, limits: LimitSettings, budget: ByteBudget, arrived: float
) -> AsyncIterator[bytes]:
    """The body of ``request`` (which arrived at ``arrived``, a ``perf_counter`` value), held
    in ``budget`` for the block."""
    encoding = request.headers.get("content-encoding", "identity").strip().lower()
    if encoding != "identity":
        raise ServiceError(
            415,
            "unsupported_media_type",
            f"Content-Encoding {encoding[:32]!r} is not accepted: send the body uncompressed "
            "(a large cloud as binary, application/octet-stream, 12 bytes a point)",
        )
    limit, declared = limits.max_body_bytes, request.headers.get("content-length")
    if declared is not None:
        if not declared.isdigit():
            raise ServiceError(400, "invalid_request", f"invalid Content-Length {declared[:32]!r}")
        if int(declared) > limit:
            raise too_large(int(declared), limit)
    held = 0
    try:
        if declared is not None:
            if not budget.take(int(declared)):
                raise budget.full(int(declared), limits.retry_after_s)
            held = int(declared)
        chunks, size = [], 0
        left_s = arrived + limits.body_timeout_s - time.perf_counter()
        try:
            with anyio.fail_after(max(left_s, 0.0)):  # a trickled body must not hold its slot
                async for chunk in request.stream():
                    size += len(chunk)
                    if size > limit:
                        raise too_large(size, limit, what="request body (at least)")
                    if size > held:  # no Content-Length (or a lying one): take as it comes
                        if not budget.take(size - held, whole=size):
                            raise budget.full(size - held, limits.retry_after_s)
                        held = size
                    chunks.append(chunk)
        except TimeoutError:
            raise ServiceError(
                408,
                "timeout",
                f"the request body did not arrive within {limits.body_timeout_s:g} s",
                headers={"Connection": "close"},
            ) from None
        except ClientDisconnect:  # nobody is left to answer; 499 is nginx's code, for metrics
            raise ServiceError(
                499, "disconnected", "the client disconnected before its body arrived"
            ) from None
        body = b"".join(chunks)
        del chunks
        yield body
    finally:
        budget.give(held)
