"""ROS messages -> arrays, on messages as drivers lay them out: padded rows, big-endian data,
clouds with other fields beside x, y, z, organised clouds with holes."""

from __future__ import annotations

from types import SimpleNamespace as Msg

import numpy as np
import pytest

from itnet.recordings.bag import shared_prefix
from itnet.recordings.decode import (
    DecodeError,
    camera_intrinsics,
    cloud_points,
    depth_image,
    header_of,
)


def image(data: np.ndarray, encoding: str, step: int, big: bool = False) -> Msg:
    height = data.shape[0]
    width = data.shape[1] if data.ndim == 2 else 0
    return Msg(height=height, width=width, encoding=encoding, step=step, is_bigendian=big,
               data=np.frombuffer(data.tobytes(), np.uint8))  # fmt: skip


def test_padded_rows_and_big_endian_depth_are_read_as_they_are() -> None:
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 100
    padded = np.zeros((3, 6), dtype=np.uint16)  # rows of 12 bytes: 8 of depth, 4 of padding
    padded[:, :4] = depth
    message = image(padded, "16UC1", step=12)
    message.width = 4
    np.testing.assert_array_equal(depth_image(message), depth)
    big = image(depth.astype(">u2"), "mono16", step=8, big=True)
    got = depth_image(big)
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, depth)
    metres = (depth / 1000).astype(np.float32)
    np.testing.assert_array_equal(depth_image(image(metres, "32FC1", step=16)), metres)


def test_a_short_buffer_or_another_encoding_is_refused() -> None:
    depth = np.zeros((3, 4), dtype=np.uint16)
    short = image(depth, "16UC1", step=8)
    short.data = short.data[:-1]
    with pytest.raises(DecodeError, match="needs 3 rows of 8 bytes"):
        depth_image(short)
    with pytest.raises(DecodeError, match="'rgb8' is not a depth encoding"):
        depth_image(image(np.zeros((3, 12), np.uint8), "rgb8", step=12))


def field(name: str, offset: int, datatype: int = 7) -> Msg:
    return Msg(name=name, offset=offset, datatype=datatype, count=1)


def test_a_cloud_with_other_fields_and_holes_gives_its_points() -> None:
    layout = np.dtype({"names": ["x", "y", "z", "rgb"], "formats": ["<f8", "<f8", "<f8", "<u4"],
                       "offsets": [0, 8, 16, 28], "itemsize": 32})  # fmt: skip
    rows = np.zeros(4, dtype=layout)
    rows["x"], rows["y"], rows["z"] = [1, 2, np.nan, 4], [5, 6, np.nan, 8], [9, 10, np.nan, 12]
    rows["rgb"] = 0xFFFFFF
    message = Msg(height=2, width=2, point_step=32, is_bigendian=False,
                  fields=[field("rgb", 28, 6), field("z", 16, 8), field("x", 0, 8), field("y", 8, 8)],
                  data=np.frombuffer(rows.tobytes(), np.uint8))  # fmt: skip
    points = cloud_points(message)
    assert points.shape == (4, 3)
    np.testing.assert_array_equal(points[[0, 1, 3]], [[1, 5, 9], [2, 6, 10], [4, 8, 12]])
    assert np.isnan(points[2]).all()
    message.fields = [field("x", 0, 8), field("y", 8, 8)]
    with pytest.raises(DecodeError, match="no field z"):
        cloud_points(message)
    message.fields = [field("x", 0, 2), field("y", 8, 8), field("z", 16, 8)]
    with pytest.raises(DecodeError, match="field x must be one float32 or float64"):
        cloud_points(message)


def test_camera_info_and_header() -> None:
    ros1 = Msg(K=[600.0, 0, 320.5, 0, 610.0, 240.5, 0, 0, 1])
    camera = camera_intrinsics(ros1)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (600.0, 610.0, 320.5, 240.5)
    assert camera_intrinsics(Msg(k=np.asarray(ros1.K))) == camera
    with pytest.raises(DecodeError, match="uncalibrated"):
        camera_intrinsics(Msg(k=np.zeros(9)))
    stamped = Msg(header=Msg(stamp=Msg(sec=12, nanosec=345), frame_id="cam"))
    assert header_of(stamped) == (12_000_000_345, "cam")


def test_the_camera_info_beside_an_image_is_the_one_sharing_its_namespace() -> None:
    assert shared_prefix("/camera/depth/camera_info", "/camera/depth/image_rect_raw") == 3
    assert shared_prefix("/camera/color/camera_info", "/camera/depth/image_rect_raw") == 2


def test_compressed_depth_of_millimetres_and_of_inverse_metres() -> None:
    import struct

    from itnet.recordings.decode import compressed_depth
    from itnet.scene.depth_io import depth_to_png

    depth = (np.arange(12, dtype=np.uint16).reshape(3, 4) + 1) * 250
    packed = struct.pack("<iff", 0, 0.0, 0.0) + depth_to_png(depth)
    message = Msg(format="16UC1; compressedDepth png", data=np.frombuffer(packed, np.uint8))
    np.testing.assert_array_equal(compressed_depth(message), depth)
    # 32FC1: the PNG holds A / (z - B) per pixel, 0 where there is no depth
    quant_a, quant_b = 100.0, -10.0
    metres = np.array([[0.5, 1.0], [2.0, 0.0]])
    values = np.where(metres > 0, np.round(quant_a / np.where(metres > 0, metres, 1) + quant_b), 0)
    packed = struct.pack("<iff", 0, quant_a, quant_b) + depth_to_png(values.astype(np.uint16))
    got = compressed_depth(
        Msg(format="32FC1; compressedDepth png", data=np.frombuffer(packed, np.uint8))
    )
    np.testing.assert_allclose(got, metres, atol=0.02)
    with pytest.raises(DecodeError, match="not a compressedDepth image"):
        compressed_depth(Msg(format="png", data=np.zeros(20, np.uint8)))
