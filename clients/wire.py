"""What travels between a client and the itnet service: request encoding, replies, errors.

Shared by the sync and async clients; numpy and the standard library only (no service, no torch).

Requests (SPEC.md):

* JSON: ``{"points": [[x, y, z], ...], "budget_ms": ..., "max_iterations": ..., "model": ...}``;
* binary: the body is little-endian float32 N x 3 (``Content-Type: application/octet-stream``)
  and the other fields are query parameters;
* a scene (``POST /v1/scene``): a 16-bit PNG depth image, a ``.npy`` depth image or a float32
  cloud as the body, the intrinsics and the rest in the query.

Replies: every pose is T_canonical_from_input (4x4, the cloud's units), with ``quat_wxyz`` and
``quat_xyzw`` (the same rotation, scalar first / last) and ``translation``.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar
from urllib.parse import urlsplit, urlunsplit

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.pose.request import PoseRequest
from itnet.request_fields import is_xyz

if TYPE_CHECKING:
    from pydantic import BaseModel

    from itnet.alignment.request import AlignRequest
    from itnet.scene.request import SceneRequest

ESTIMATE_PATH = "/v1/estimate"
SCENE_PATH = "/v1/scene"
ALIGN_PATH = "/v1/align"
STREAM_PATH = "/v1/estimate/stream"
BINARY = {"Content-Type": "application/octet-stream"}


class ItnetClientError(Exception):
    """Base of the client's errors."""


class ItnetRequestError(ItnetClientError):
    """The service refused the request (4xx/5xx, or an ``error`` message on the stream)."""

    def __init__(self, status: int | None, detail: object, kind: str | None = None) -> None:
        self.status, self.detail, self.kind = status, detail, kind  # kind: the service's label
        where = f"HTTP {status}" if status is not None else "stream error"
        super().__init__(f"{where}: {detail}")


class ItnetConnectionError(ItnetClientError):
    """The service could not be reached, or the connection ended before the result."""


@dataclass(frozen=True)
class Estimate:
    """The pose after ``iteration`` steps, as the service reported it."""

    iteration: int
    T_canonical_from_input: NDArray[np.float64]  # 4x4
    quat_wxyz: NDArray[np.float64]  # (4,)
    quat_xyzw: NDArray[np.float64]  # (4,)
    translation: NDArray[np.float64]  # (3,)
    elapsed_ms: float
    update_rotation_deg: float
    update_translation: float  # the cloud's units
    raw: dict[str, Any] = field(repr=False, default_factory=dict)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Estimate:
        return cls(int(data["iteration"]), *_pose_arrays(data), float(data["elapsed_ms"]),
                   float(data["update_rotation_deg"]), float(data["update_translation"]),
                   data)  # fmt: skip


@dataclass(frozen=True)
class EstimateResult:
    """The final answer: pose, iterations run, why it stopped (``budget``, ``max_iterations``,
    ``converged``, ``cancelled``), total time, model name, and every per-iteration estimate
    (those of the reply, or those a stream delivered)."""

    T_canonical_from_input: NDArray[np.float64]  # 4x4
    quat_wxyz: NDArray[np.float64]
    quat_xyzw: NDArray[np.float64]
    translation: NDArray[np.float64]
    iterations: int
    stopped_by: str
    elapsed_ms: float
    model: str
    estimates: list[Estimate]
    raw: dict[str, Any] = field(repr=False, default_factory=dict)

    @classmethod
    def from_dict(
        cls, data: dict[str, Any], estimates: list[Estimate] | None = None
    ) -> EstimateResult:
        if estimates is None:
            estimates = [Estimate.from_dict(e) for e in data.get("estimates", [])]
        return cls(*_pose_arrays(data), int(data["iterations"]), str(data["stopped_by"]),
                   float(data["elapsed_ms"]), str(data.get("model", "")), estimates,
                   data)  # fmt: skip

    @property
    def ensemble(self) -> int:
        """Runs fused into each estimate (1: a single run)."""
        return int(self.raw.get("ensemble") or 1)

    @property
    def verified(self) -> bool | None:
        """Where ``verify`` was on: True if it ran and anchored the fusion (on the run the
        verifier found likeliest, or the firmest by the probes), False if the budget could not
        hold it; None where it was off."""
        verified = self.raw.get("verified")
        return None if verified is None else bool(verified)

    @property
    def rechecked(self) -> bool | None:
        """Where the verifier doubted a single run: True if the recheck's runs ran, False if
        the budget could not hold them; None where it did not doubt it (or recheck was off)."""
        rechecked = self.raw.get("rechecked")
        return None if rechecked is None else bool(rechecked)


def _pose_arrays(data: dict[str, Any]) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    try:
        pose = np.asarray(data["T_canonical_from_input"], dtype=np.float64).reshape(4, 4)
        quats = [np.asarray(data[k], np.float64).reshape(4) for k in ("quat_wxyz", "quat_xyzw")]
        return pose, quats[0], quats[1], np.asarray(data["translation"], np.float64).reshape(3)
    except (KeyError, ValueError, TypeError) as err:
        raise ItnetClientError(f"malformed reply from the service: {err!r}") from None


def as_cloud(points: ArrayLike) -> NDArray[np.float64]:
    """Any (N, 3) array-like -> float64 array; the service checks everything else."""
    cloud = np.asarray(points, dtype=np.float64)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {cloud.shape}")
    return cloud


Request = TypeVar("Request", bound="BaseModel")


def _with_fields(kind: type[Request], what: str, request: Request | None,
                 fields: dict[str, Any]) -> Request:  # fmt: skip
    """``request`` (default: the service's defaults) with ``fields`` (any of ``kind``'s) set on
    top; arrays and tuples of a direction field (``Xyz``) as the JSON lists it takes. Raises
    TypeError naming an unknown field (``what`` says whose), ValueError (pydantic's) for a value
    it refuses."""
    unknown = sorted(set(fields) - set(kind.model_fields))
    if unknown:
        raise TypeError(f"unknown {what} option(s) {', '.join(map(repr, unknown))}")
    base = {} if request is None else request.model_dump(exclude_unset=True)
    values = {k: v for k, v in {**base, **fields}.items() if v is not None}
    for name, spec in kind.model_fields.items():
        if name in values and is_xyz(spec.annotation):
            values[name] = [float(v) for v in np.asarray(values[name], dtype=np.float64).ravel()]
    return kind.model_validate(values, strict=False)


def pose_request(request: PoseRequest | None, fields: dict[str, Any]) -> PoseRequest:
    """The request to send: ``request`` (default: the service's defaults) with ``fields`` (any
    of PoseRequest's: budget_ms, max_iterations, model, ensemble, mirror, verify, recheck,
    centre, viewpoint, up, units) set on top. Raises TypeError for a name PoseRequest does not
    have, ValueError (pydantic's) for a value it refuses."""
    return _with_fields(PoseRequest, "request", request, fields)


def align_request(request: AlignRequest | None, fields: dict[str, Any]) -> AlignRequest:
    """The alignment request to send: ``request`` (default: the service's defaults) with
    ``fields`` (any of AlignRequest's) set on top. Raises TypeError for a name AlignRequest
    does not have, ValueError (pydantic's) for a value it refuses."""
    from itnet.alignment.request import AlignRequest

    return _with_fields(AlignRequest, "alignment", request, fields)


def request_fields(request: PoseRequest) -> dict[str, Any]:
    """The JSON request's non-point fields (those not left to the service's defaults, and the
    budget)."""
    return {"budget_ms": request.budget_ms, **request.model_dump(exclude_defaults=True)}


def json_request(points: ArrayLike, fields: dict[str, Any]) -> dict[str, Any]:
    return {"points": as_cloud(points).tolist(), **fields}


def binary_body(points: ArrayLike) -> bytes:
    """(N, 3) -> little-endian float32 bytes, row after row (12 bytes a point)."""
    return np.ascontiguousarray(as_cloud(points), dtype="<f4").tobytes()


def scene_body(scene: ArrayLike | bytes | str | Path) -> tuple[bytes, str]:
    """A scene -> the body and its content type: a ``.png`` or ``.npy`` file's bytes, PNG bytes,
    a cloud (N, 3) as float32 (metres, the camera's frame), or a depth image (H, W) as ``.npy``
    (float: metres; integers: depth units)."""
    if isinstance(scene, (str, Path)):
        kinds = {".png": "image/png", ".npy": "application/x-npy"}
        kind = kinds.get(Path(scene).suffix.lower())
        if kind is None:
            raise ValueError(f"{scene}: send a .png or .npy file, or the cloud's points")
        return Path(scene).read_bytes(), kind
    if isinstance(scene, bytes):
        return scene, "image/png"
    array = np.asarray(scene)
    if array.ndim == 2 and array.shape[1] == 3:
        return binary_body(array), BINARY["Content-Type"]
    if array.ndim != 2:
        raise ValueError(f"a depth image is (H, W) and a cloud (N, 3), got {array.shape}")
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue(), "application/x-npy"


def scene_request(
    scene: ArrayLike | bytes | str | Path,
    intrinsics: tuple[float, float, float, float] | None,
    request: SceneRequest | None,
    indices: bool,
    fields: dict[str, Any],
) -> tuple[bytes, dict[str, str], dict[str, str]]:
    """``POST /v1/scene``'s body (``scene_body``), query and headers: the intrinsics (fx, fy,
    cx, cy) where given, ``indices``, and ``request`` (default: the service's defaults) with
    ``fields`` (any of SceneRequest's) set on top, in the query. Raises TypeError for a name
    SceneRequest does not have, ValueError (pydantic's) for a value it refuses."""
    from itnet.scene.request import SceneRequest

    asked = _with_fields(SceneRequest, "scene", request, fields)
    body, kind = scene_body(scene)
    query: dict[str, str] = {"indices": str(indices).lower(), **asked.to_query()}
    if intrinsics is not None:
        fx, fy, cx, cy = (float(v) for v in intrinsics)
        query.update(fx=repr(fx), fy=repr(fy), cx=repr(cx), cy=repr(cy))
    return body, query, {"Content-Type": kind}


def error_detail(text: str) -> tuple[object, str | None]:
    """An error body -> (its ``detail``, its ``kind``), or (the body, None) when it is not JSON
    of that shape."""
    try:
        body = json.loads(text)
    except ValueError:
        return text, None
    if not isinstance(body, dict):
        return body, None
    return body.get("detail", body), body.get("kind")


def reply_json(status: int, text: str) -> Any:
    """An HTTP reply's JSON body, or ItnetRequestError (status >= 400) / ItnetClientError."""
    if status >= 400:
        raise ItnetRequestError(status, *error_detail(text))
    try:
        return json.loads(text)
    except ValueError:
        raise ItnetClientError(f"the service did not answer JSON: {text[:200]!r}") from None


def websocket_url(base_url: str) -> str:
    """http(s)://host:port/prefix -> ws(s)://host:port/prefix/v1/estimate/stream."""
    parts = urlsplit(base_url)
    scheme = {"http": "ws", "https": "wss"}.get(parts.scheme, parts.scheme)
    return urlunsplit((scheme, parts.netloc, parts.path.rstrip("/") + STREAM_PATH, "", ""))


def parse_message(text: str | bytes) -> tuple[str, dict[str, Any]]:
    """A stream message -> (type, body). Raises ItnetRequestError for ``error`` messages."""
    try:
        message = json.loads(text)
        kind = message["type"]
    except (ValueError, KeyError, TypeError):
        raise ItnetClientError(f"malformed stream message: {str(text)[:200]!r}") from None
    if kind == "error":
        raise ItnetRequestError(None, message.get("detail"), message.get("kind"))
    return kind, message
