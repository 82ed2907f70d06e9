"""What a scene arrives as -> the camera-frame cloud its objects are found in.

* A depth image (H, W): a 16-bit PNG (depth units, millimetres unless ``depth_scale`` says how
  many per metre), or a ``.npy`` array (float: metres; integers: depth units), with the camera's
  intrinsics. Pixels without a reading (0, NaN) are skipped; an object's ``indices`` are then
  flat pixel indices ``v * W + u``.
* A scene cloud (N, 3): ``.ply``, ``.pcd``, ``.xyz``, ``.npy`` or an array, in the camera's frame
  (x right, y down, z ahead), metres. Rows with NaN or infinite coordinates are skipped (an
  organised cloud's missing readings); an object's ``indices`` are rows of the cloud.

Bounded: at most ``SceneLimits.max_pixels`` pixels and ``max_points`` points (the memory a scene
may hold: about 100 bytes a point while it is segmented).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.scene.camera import Intrinsics, SceneInputError, SceneTooLargeError, depth_to_cloud
from itnet.scene.depth_io import depth_in_metres, png_to_depth, read_bytes, read_npy

IMAGE_SUFFIXES = (".png",)
MAX_COORDINATE_M = 1e4  # a scene is a room, not a continent


@dataclass(frozen=True)
class SceneLimits:
    """The largest scene accepted."""

    max_pixels: int = 1280 * 1024
    max_points: int = 1280 * 1024
    max_depth_m: float = 20.0


@dataclass
class SceneInput:
    """A scene's valid points (N, 3) in the camera frame, metres, and where each came from
    (``indices`` (N,): flat pixel indices of a depth image of ``image_shape`` (H, W), or rows of
    a cloud, ``image_shape`` None)."""

    points: NDArray[np.float64]
    indices: NDArray[np.int64]
    image_shape: tuple[int, int] | None = None


def from_depth(
    image: NDArray, intrinsics: Intrinsics | None, depth_scale: float | None = None,
    limits: SceneLimits = SceneLimits(),
) -> SceneInput:  # fmt: skip
    """A depth image (H, W) -> its SceneInput. SceneInputError: no intrinsics, too large, no
    valid depth."""
    if intrinsics is None:
        raise SceneInputError(
            "a depth image needs the camera's intrinsics (fx, fy, cx, cy, or a JSON file of them)"
        )
    if image.ndim != 2:
        raise SceneInputError(f"a depth image must be 2-D (H, W), got shape {image.shape}")
    if image.size > limits.max_pixels:
        raise SceneTooLargeError(
            f"the depth image has {image.shape[1]}x{image.shape[0]} pixels, over the limit of "
            f"{limits.max_pixels}"
        )
    depth = depth_in_metres(image, depth_scale)
    points, pixels = depth_to_cloud(depth, intrinsics, limits.max_depth_m)
    if len(points) == 0:
        raise SceneInputError(
            f"the depth image has no valid depth (every pixel is 0, NaN or beyond "
            f"{limits.max_depth_m:g} m)"
        )
    return SceneInput(points, pixels, (int(image.shape[0]), int(image.shape[1])))


def from_cloud(points: NDArray, limits: SceneLimits = SceneLimits()) -> SceneInput:
    """A scene cloud (N, 3) -> its SceneInput. SceneInputError: wrong shape, too many points,
    no finite point, coordinates beyond a room."""
    cloud = np.asarray(points, dtype=np.float64)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise SceneInputError(f"a scene cloud must have shape (N, 3), got {cloud.shape}")
    if len(cloud) > limits.max_points:
        raise SceneTooLargeError(
            f"the scene has {len(cloud)} points, over the limit of {limits.max_points}"
        )
    rows = np.flatnonzero(np.isfinite(cloud).all(axis=1))
    if len(rows) == 0:
        raise SceneInputError("the scene cloud has no finite point")
    if np.abs(cloud[rows]).max() > MAX_COORDINATE_M:
        raise SceneInputError(
            f"coordinates beyond {MAX_COORDINATE_M:g} m: a scene cloud must be in metres"
        )
    return SceneInput(cloud[rows], rows)


def from_array(
    array: NDArray, intrinsics: Intrinsics | None = None, depth_scale: float | None = None,
    limits: SceneLimits = SceneLimits(),
) -> SceneInput:  # fmt: skip
    """An (N, 3) array is a cloud, any other 2-D array a depth image."""
    if array.ndim == 2 and array.shape[1] == 3:
        return from_cloud(array, limits)
    return from_depth(array, intrinsics, depth_scale, limits)


def from_png(
    data: bytes, intrinsics: Intrinsics | None, depth_scale: float | None = None,
    limits: SceneLimits = SceneLimits(),
) -> SceneInput:  # fmt: skip
    """PNG bytes (16-bit greyscale) -> its SceneInput."""
    if intrinsics is None:  # before decoding: the cheaper refusal
        return from_depth(np.zeros((0, 0), np.uint16), None)
    return from_depth(png_to_depth(data, limits.max_pixels), intrinsics, depth_scale, limits)


def from_file(
    path: Path, intrinsics: Intrinsics | None = None, depth_scale: float | None = None,
    limits: SceneLimits = SceneLimits(),
) -> SceneInput:  # fmt: skip
    """A scene file (.png depth image; .npy depth image or cloud; .ply/.pcd/.xyz cloud) -> its
    SceneInput. SceneInputError saying what is wrong."""
    from itnet.cloud_io import CloudReadError, read_cloud

    suffix = path.suffix.lower()
    if suffix in IMAGE_SUFFIXES:
        return from_png(read_bytes(path), intrinsics, depth_scale, limits)
    if suffix == ".npy":
        return from_array(read_npy(read_bytes(path)), intrinsics, depth_scale, limits)
    try:
        return from_cloud(read_cloud(path), limits)
    except CloudReadError as err:
        raise SceneInputError(str(err).removeprefix(f"{path}: ")) from None
