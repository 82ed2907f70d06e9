"""Client-facing errors: one exception type with its HTTP status, error kind and message.

Every 4xx says what is wrong in ``detail``; ``kind`` is the label counted in /metrics. Over a
WebSocket the same error is a ``{"type": "error"}`` message followed by a close code.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from itnet.pose.errors import OverloadedError, PoseError

# RFC 6455 close codes: policy violation, unsupported data, message too big, try again later,
# internal error.
WS_POLICY, WS_UNSUPPORTED, WS_TOO_BIG, WS_TRY_LATER, WS_INTERNAL = 1008, 1003, 1009, 1013, 1011
_WS_CODES = {413: WS_TOO_BIG, 415: WS_UNSUPPORTED, 503: WS_TRY_LATER, 500: WS_INTERNAL}


class ServiceError(Exception):
    """A request the service refuses: ``status`` (HTTP), ``kind`` (metrics label), ``detail``."""

    def __init__(
        self, status: int, kind: str, detail: str, headers: Mapping[str, str] | None = None
    ) -> None:
        super().__init__(detail)
        self.status, self.kind, self.detail = status, kind, detail
        self.headers = dict(headers or {})

    @classmethod
    def of(cls, err: PoseError) -> ServiceError:
        """The reply to a request the pose pipeline refused: its status, kind and message (an
        overloaded one with its Retry-After)."""
        headers = {}
        if isinstance(err, OverloadedError):
            headers["Retry-After"] = str(err.retry_after_s)
        return cls(err.status, err.kind, str(err), headers)

    @property
    def ws_close_code(self) -> int:
        """The WebSocket close code that fits this error (1008 for any other client error)."""
        return _WS_CODES.get(self.status, WS_POLICY)

    def body(self) -> dict[str, str]:
        return {"detail": self.detail, "kind": self.kind}

    def encoded(self) -> tuple[bytes, list[tuple[bytes, bytes]]]:
        """The reply as a protocol writes it without the app: the JSON body and its headers
        (content type and length, then this error's own, their names in lower case)."""
        body = json.dumps(self.body()).encode()
        headers = [(b"content-type", b"application/json"),
                   (b"content-length", str(len(body)).encode())]  # fmt: skip
        return body, headers + [(k.lower().encode(), v.encode()) for k, v in self.headers.items()]


def malformed_json(message: str) -> ServiceError:
    return ServiceError(400, "malformed_json", f"malformed JSON: {message}")


def too_large(size: int, limit: int, what: str = "request body") -> ServiceError:
    return ServiceError(413, "too_large", f"{what} of {size} bytes exceeds the limit of {limit}")


def describe_errors(errors: Sequence[Mapping[str, Any]], shown: int = 3) -> str:
    """Pydantic errors -> one line, ``"budget_ms: Input should be greater than 0"``.

    Errors with the same message are merged (``"points.0, points.1 and 198 more: ..."``); the
    offending input is never echoed (it may be a million points).
    """
    where: dict[str, list[str]] = {}
    for error in errors:
        where.setdefault(str(error.get("msg", "invalid")), []).append(
            _location(error.get("loc", ()))
        )
    parts = []
    for message, locations in list(where.items())[:shown]:
        named = ", ".join(locations[:shown])
        more = len(locations) - shown
        parts.append(f"{named}{f' and {more} more' if more > 0 else ''}: {message}")
    return "; ".join(parts)


def _location(loc: Iterable[Any], limit: int = 64) -> str:
    """``('body', 'points', 0)`` -> ``'points.0'``; a part longer than ``limit`` (a client's
    field name may be a megabyte) is cut, never echoed whole."""
    parts = [str(p) for p in loc if p not in ("body", "query")]
    parts = [p if len(p) <= limit else f"{p[:limit]}... ({len(p)} characters)" for p in parts]
    return ".".join(parts) or "request"
