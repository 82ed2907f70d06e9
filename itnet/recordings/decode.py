"""ROS messages -> arrays: a depth ``Image`` (or a ``CompressedImage`` of image_transport's
``compressedDepth``) -> (H, W) depth, a ``PointCloud2`` -> (N, 3) points, a ``CameraInfo`` ->
Intrinsics, a ``Header`` -> (stamp in ns, frame_id).

Pure functions of the deserialised messages (any object with the messages' field names, ROS 1
or ROS 2: ``K`` or ``k``); no bag is read here. Each raises DecodeError with a one-line reason.
"""

from __future__ import annotations

import struct
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from itnet.scene.camera import Intrinsics, SceneInputError
from itnet.scene.depth_io import png_to_depth

# Depth encodings (REP 118, sensor_msgs/image_encodings): integer depth units (millimetres
# unless told otherwise), or float metres.
INTEGER_DEPTH = {"16UC1": np.uint16, "mono16": np.uint16}
FLOAT_DEPTH = {"32FC1": np.float32, "64FC1": np.float64}
DEPTH_ENCODINGS = (*INTEGER_DEPTH, *FLOAT_DEPTH)

# sensor_msgs/PointField datatypes that x, y and z may have.
POINT_FIELD_TYPES = {7: np.float32, 8: np.float64}


class DecodeError(ValueError):
    """A message that cannot be turned into depth, points or intrinsics; the message says why."""


def header_of(message: Any) -> tuple[int, str]:
    """A stamped message -> (its header's stamp in nanoseconds, its frame_id)."""
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec), str(message.header.frame_id)


def depth_image(message: Any) -> NDArray:
    """A ``sensor_msgs/Image`` of a depth encoding -> (H, W): uint16 depth units for ``16UC1`` /
    ``mono16``, float metres for ``32FC1`` / ``64FC1`` (rows padded to ``step`` are cut, big-endian
    data swapped). DecodeError for any other encoding or a buffer shorter than it says."""
    encoding = str(message.encoding)
    dtype = INTEGER_DEPTH.get(encoding) or FLOAT_DEPTH.get(encoding)
    if dtype is None:
        raise DecodeError(
            f"encoding {encoding!r} is not a depth encoding ({', '.join(DEPTH_ENCODINGS)})"
        )
    height, width, step = int(message.height), int(message.width), int(message.step)
    item = np.dtype(dtype).itemsize
    data = np.asarray(message.data, dtype=np.uint8)
    if height <= 0 or width <= 0 or step < width * item or len(data) < height * step:
        raise DecodeError(
            f"a {width}x{height} {encoding} image needs {height} rows of {step} bytes "
            f"(at least {width * item}), got {len(data)} bytes"
        )
    rows = data[: height * step].reshape(height, step)[:, : width * item]
    order: Literal["<", ">"] = ">" if message.is_bigendian else "<"
    return np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order)).astype(dtype)


COMPRESSED_DEPTH = "compressedDepth"
CONFIG_HEADER = struct.Struct("<iff")  # compressed_depth_image_transport's: format, quantisation


def is_compressed_depth(message: Any) -> bool:
    """Whether a ``sensor_msgs/CompressedImage`` holds depth (image_transport's compressedDepth)."""
    return COMPRESSED_DEPTH in str(message.format)


def compressed_depth(message: Any) -> NDArray:
    """A ``sensor_msgs/CompressedImage`` of ``compressedDepth`` (its ``format`` '16UC1;
    compressedDepth png' or '32FC1; compressedDepth png') -> (H, W): uint16 depth units for
    16UC1, float metres for 32FC1 (stored as quantised inverse depth, ``A / (v - B)``)."""
    text = str(message.format)
    if not is_compressed_depth(message):
        raise DecodeError(f"format {text!r} is not a compressedDepth image")
    encoding = text.split(";")[0].strip()
    if encoding not in ("16UC1", "32FC1"):
        raise DecodeError(f"compressedDepth of {encoding!r}: only 16UC1 and 32FC1 are read")
    data = bytes(np.asarray(message.data, dtype=np.uint8))
    if len(data) <= CONFIG_HEADER.size:
        raise DecodeError("compressedDepth data shorter than its header")
    _, quant_a, quant_b = CONFIG_HEADER.unpack_from(data)
    try:
        image = png_to_depth(data[CONFIG_HEADER.size :])
    except SceneInputError as err:
        raise DecodeError(f"compressedDepth: {err}") from None
    if encoding == "16UC1":
        return image
    values = image.astype(np.float64)
    with np.errstate(divide="ignore"):
        depth = np.where(values > 0, quant_a / (values - quant_b), 0.0)
    return np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)


def cloud_points(message: Any) -> NDArray[np.float64]:
    """A ``sensor_msgs/PointCloud2`` with float ``x``, ``y``, ``z`` fields -> (N, 3) points, every
    point of it (an organised cloud's missing readings stay NaN; the scene drops them)."""
    fields = {str(f.name): f for f in message.fields}
    if missing := [n for n in "xyz" if n not in fields]:
        raise DecodeError(f"the cloud has no field {', '.join(missing)}")
    count = int(message.height) * int(message.width)
    point_step = int(message.point_step)
    data = np.asarray(message.data, dtype=np.uint8)
    if count == 0:
        return np.zeros((0, 3))
    if point_step <= 0 or len(data) < count * point_step:
        raise DecodeError(
            f"{count} points of {point_step} bytes need {count * point_step} bytes, got {len(data)}"
        )
    order: Literal["<", ">"] = ">" if message.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for name in "xyz":
        field = fields[name]
        kind = POINT_FIELD_TYPES.get(int(field.datatype))
        if kind is None or int(field.count) != 1:
            raise DecodeError(f"field {name} must be one float32 or float64 (datatype 7 or 8)")
        names.append(name)
        formats.append(np.dtype(kind).newbyteorder(order))
        offsets.append(int(field.offset))
    layout = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                       "itemsize": point_step})  # fmt: skip
    rows = data[: count * point_step].view(layout)
    return np.stack([rows[n].astype(np.float64) for n in "xyz"], axis=1)


def camera_intrinsics(message: Any) -> Intrinsics:
    """A ``sensor_msgs/CameraInfo`` -> its pinhole Intrinsics (from ``K``/``k``). DecodeError for
    an uncalibrated camera (K all zeros, as drivers publish before calibration)."""
    k = np.asarray(getattr(message, "k", getattr(message, "K", ())), dtype=np.float64).ravel()
    if k.shape != (9,) or not np.isfinite(k).all() or k[0] <= 0 or k[4] <= 0:
        raise DecodeError("its K matrix gives no focal length (an uncalibrated camera)")
    try:
        return Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]))
    except SceneInputError as err:
        raise DecodeError(str(err)) from None
