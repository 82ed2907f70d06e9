"""The depth camera: pinhole intrinsics, where they come from, and depth image -> cloud.

Camera frame (OpenCV, ROS optical frames): x right, y down, z ahead along the optical axis,
metres. A pixel (u, v) with depth z (along the optical axis, not along the ray) is the point
``((u - cx) z / fx, (v - cy) z / fy, z)``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray


class SceneInputError(ValueError):
    """A scene input that cannot be used: missing intrinsics, wrong bit depth, no valid depth,
    too large, unreadable. The message says what is wrong, in one line."""


class SceneTooLargeError(SceneInputError):
    """A scene over the stated limits (pixels, points)."""


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera: focal lengths and principal point in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise SceneInputError("intrinsics fx, fy, cx, cy must be finite numbers")
        if self.fx <= 0 or self.fy <= 0:
            raise SceneInputError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_deg: float) -> Intrinsics:
        """Square pixels, the principal point at the image centre, ``horizontal_fov_deg`` wide."""
        f = (width / 2) / math.tan(math.radians(horizontal_fov_deg) / 2)
        return cls(f, f, (width - 1) / 2, (height - 1) / 2)

    def as_dict(self) -> dict[str, float]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}


def parse_intrinsics(text: str) -> Intrinsics:
    """'fx,fy,cx,cy' (four numbers), or the path of a JSON file (``intrinsics_from_json``)."""
    parts = text.split(",")
    if len(parts) == 4:
        try:
            return Intrinsics(*(float(p) for p in parts))
        except ValueError:
            raise SceneInputError(
                f"intrinsics {text!r}: expected four numbers fx,fy,cx,cy"
            ) from None
    path = Path(text)
    if not path.is_file():
        raise SceneInputError(f"intrinsics {text!r}: neither 'fx,fy,cx,cy' nor a JSON file")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SceneInputError(f"intrinsics {path}: not readable JSON ({err})") from None
    return intrinsics_from_json(data)


def intrinsics_from_json(data: Any) -> Intrinsics:
    """A JSON object in one of three forms -> Intrinsics:

    * ``{"fx", "fy", "cx", "cy"}``;
    * ROS ``sensor_msgs/CameraInfo``: ``"K"`` (ROS 1) or ``"k"`` (ROS 2), the 3x3 matrix
      row-major, ``[fx, 0, cx, 0, fy, cy, 0, 0, 1]``;
    * Open3D's ``PinholeCameraIntrinsic`` as ``o3d.io.write_pinhole_camera_intrinsic`` writes it:
      ``"intrinsic_matrix"``, the 3x3 matrix column-major, ``[fx, 0, 0, 0, fy, 0, cx, cy, 1]``.
    """
    if not isinstance(data, dict):
        raise SceneInputError("intrinsics JSON must be an object")
    try:
        if all(k in data for k in ("fx", "fy", "cx", "cy")):
            return Intrinsics(*(float(data[k]) for k in ("fx", "fy", "cx", "cy")))
        for key, order in (("K", "C"), ("k", "C"), ("intrinsic_matrix", "F")):
            if key in data:
                m = np.asarray(data[key], dtype=np.float64).reshape((3, 3), order=order)  # type: ignore[call-overload]
                return Intrinsics(float(m[0, 0]), float(m[1, 1]), float(m[0, 2]), float(m[1, 2]))
    except (TypeError, ValueError) as err:
        raise SceneInputError(f"intrinsics JSON: {err}") from None
    raise SceneInputError(
        "intrinsics JSON needs fx, fy, cx, cy, or K / k (ROS CameraInfo), or intrinsic_matrix "
        "(Open3D)"
    )


def depth_to_cloud(
    depth_m: NDArray, intrinsics: Intrinsics, max_depth_m: float = 20.0
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Depth image (H, W) in metres (0, NaN or beyond ``max_depth_m``: no reading) ->
    (camera-frame points (N, 3), their flat pixel indices (N,) into the image, row-major)."""
    depth = np.asarray(depth_m, dtype=np.float64)
    w = depth.shape[1]
    valid = np.isfinite(depth) & (depth > 0) & (depth <= max_depth_m)
    pixels = np.flatnonzero(valid)
    z = depth.ravel()[pixels]
    v, u = np.divmod(pixels, w)
    points = np.empty((len(z), 3))  # filled a column at a time: np.stack(axis=1) is 3x slower
    points[:, 0] = (u - intrinsics.cx) * z / intrinsics.fx
    points[:, 1] = (v - intrinsics.cy) * z / intrinsics.fy
    points[:, 2] = z
    return points, pixels
