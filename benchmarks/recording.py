"""Recordings made with rosbags, as a depth camera's driver would log them: a depth image topic
(16UC1 millimetres or 32FC1 metres) with its CameraInfo beside it, or a PointCloud2 topic, in a
ROS 1 bag or a ROS 2 bag (sqlite3 or MCAP). The tests and the recording benchmark build theirs
here from the shipped example scene.

    write_recording(Path("scene.bag"), "ros1", [depth] * 30, intrinsics)

``python -m benchmarks.recording`` writes the example recording ``itnet/examples/scene.bag``:
the example scene as a camera turning slowly to its left sees it, 5 frames at 5 frames/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.scene.camera import Intrinsics, depth_to_cloud

KINDS = ("ros1", "sqlite3", "mcap")
DEPTH_TOPIC = "/camera/depth/image_rect_raw"
INFO_TOPIC = "/camera/depth/camera_info"
CLOUD_TOPIC = "/camera/depth/points"
FRAME_ID = "camera_depth_optical_frame"


@dataclass(frozen=True)
class Layout:
    """What the recording holds: depth images (and their camera info), and/or clouds."""

    depth: bool = True
    camera_info: bool = True
    cloud: bool = False
    encoding: str = "16UC1"  # or 32FC1 (metres); mono8 (no depth encoding); compressedDepth
    # (a CompressedImage of image_transport's compressedDepth, 16UC1 in a PNG)
    calibrated: bool = True  # False: CameraInfo's K all zeros, as before calibration
    period_ns: int = 33_333_333  # 30 frames a second
    start_ns: int = 1_700_000_000 * 10**9


def write_recording(path: Path, kind: str, frames: list[NDArray], intrinsics: Intrinsics,
                    layout: Layout = Layout(), stamps_ns: list[int] | None = None,
                    compressed: bool = False) -> Path:  # fmt: skip
    """Write ``frames`` (each (H, W) uint16 millimetres) as a recording of ``kind`` (ros1,
    sqlite3, mcap) at ``path`` (a .bag file for ROS 1, a folder for ROS 2); ``stamps_ns``: each
    frame's header stamp (default: the log time). The frames are logged ``layout``'s period apart;
    ``compressed``: bz2 chunks (ROS 1)."""
    store = _store(kind)
    logged = [layout.start_ns + i * layout.period_ns for i in range(len(frames))]
    stamps = stamps_ns or logged
    with _writer(path, kind) as writer:

        def connection(wanted: bool, topic: str, msgtype: str):  # type: ignore[no-untyped-def]
            return writer.add_connection(topic, msgtype, typestore=store) if wanted else None

        compressed = layout.encoding == "compressedDepth"
        image_c = connection(layout.depth, DEPTH_TOPIC + ("/compressedDepth" if compressed else ""),
                             "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image")  # fmt: skip
        info_c = connection(layout.camera_info, INFO_TOPIC, "sensor_msgs/msg/CameraInfo")
        cloud_c = connection(layout.cloud, CLOUD_TOPIC, "sensor_msgs/msg/PointCloud2")
        serialise = store.serialize_ros1 if kind == "ros1" else store.serialize_cdr
        for i, (depth, stamp, log_time) in enumerate(zip(frames, stamps, logged)):
            header = _header(store, stamp, i, kind)
            messages = []
            if layout.camera_info:
                k = intrinsics if layout.calibrated else None
                messages.append((info_c, camera_info(store, header, depth.shape, k, kind)))
            if layout.depth:
                messages.append((image_c, depth_image(store, header, depth, layout.encoding)))
            if layout.cloud:
                points, _ = depth_to_cloud(depth / 1000.0, intrinsics)
                messages.append((cloud_c, point_cloud(store, header, points)))
            for connection, message in messages:
                writer.write(connection, log_time, serialise(message, connection.msgtype))
    return path


def write_clouds(path: Path, kind: str, clouds: list[NDArray], topic: str = CLOUD_TOPIC,
                 period_ns: int = 100_000_000) -> Path:  # fmt: skip
    """Write ``clouds`` (each (N, 3)) as PointCloud2 messages on ``topic``, ``period_ns`` apart."""
    store = _store(kind)
    serialise = store.serialize_ros1 if kind == "ros1" else store.serialize_cdr
    with _writer(path, kind) as writer:
        connection = writer.add_connection(topic, "sensor_msgs/msg/PointCloud2", typestore=store)
        for i, points in enumerate(clouds):
            stamp = Layout().start_ns + i * period_ns
            message = point_cloud(store, _header(store, stamp, i, kind), points)
            writer.write(connection, stamp, serialise(message, connection.msgtype))
    return path


def _store(kind: str):  # type: ignore[no-untyped-def]
    from rosbags.typesys import Stores, get_typestore

    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    return get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)


def _writer(path: Path, kind: str):  # type: ignore[no-untyped-def]
    if kind == "ros1":
        from rosbags.rosbag1 import Writer as Ros1Writer

        return Ros1Writer(path)
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Ros2Writer

    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    return Ros2Writer(path, version=9, storage_plugin=plugin)


def _header(store, stamp_ns: int, seq: int, kind: str):  # type: ignore[no-untyped-def]
    sec, nanosec = divmod(stamp_ns, 10**9)
    time = store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    header = store.types["std_msgs/msg/Header"]
    if kind == "ros1":
        return header(seq=seq, stamp=time, frame_id=FRAME_ID)
    return header(stamp=time, frame_id=FRAME_ID)


def depth_image(store, header, depth: NDArray, encoding: str):  # type: ignore[no-untyped-def]
    """A sensor_msgs/Image of the depth (uint16 millimetres): 16UC1 as it is, 32FC1 in metres,
    mono8 a grey picture of it; compressedDepth: a sensor_msgs/CompressedImage of it."""
    if encoding == "compressedDepth":
        import struct

        from itnet.scene.depth_io import depth_to_png

        data = struct.pack("<iff", 0, 0.0, 0.0) + depth_to_png(depth.astype(np.uint16))
        return store.types["sensor_msgs/msg/CompressedImage"](
            header=header, format="16UC1; compressedDepth png",
            data=np.frombuffer(data, dtype=np.uint8),
        )  # fmt: skip
    data = {
        "16UC1": lambda: depth.astype(np.uint16),
        "32FC1": lambda: (depth / 1000.0).astype(np.float32),
        "mono8": lambda: (depth // 40).astype(np.uint8),
    }[encoding]()
    height, width = depth.shape
    return store.types["sensor_msgs/msg/Image"](
        header=header, height=height, width=width, encoding=encoding, is_bigendian=0,
        step=width * data.itemsize, data=np.ascontiguousarray(data).view(np.uint8).ravel(),
    )  # fmt: skip


def camera_info(store, header, shape: tuple[int, ...], intrinsics: Intrinsics | None, kind: str):  # type: ignore[no-untyped-def]
    """A sensor_msgs/CameraInfo of the pinhole camera, no distortion (None: uncalibrated, K
    all zeros)."""
    fx, fy, cx, cy = (0.0,) * 4 if intrinsics is None else (
        intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)  # fmt: skip
    k = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64)
    p = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64)
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                          width=0, do_rectify=False)  # fmt: skip
    matrices = (
        {"D": np.zeros(5), "K": k, "R": np.eye(3).ravel(), "P": p}
        if kind == "ros1"
        else {"d": np.zeros(5), "k": k, "r": np.eye(3).ravel(), "p": p}
    )
    return store.types["sensor_msgs/msg/CameraInfo"](
        header=header, height=shape[0], width=shape[1], distortion_model="plumb_bob",
        binning_x=0, binning_y=0, roi=roi, **matrices,
    )  # fmt: skip


def point_cloud(store, header, points: NDArray):  # type: ignore[no-untyped-def]
    """A sensor_msgs/PointCloud2 (unorganised, float32 x, y, z) of the points (N, 3)."""
    data = np.ascontiguousarray(points, dtype=np.float32)
    field = store.types["sensor_msgs/msg/PointField"]
    fields = [field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
    return store.types["sensor_msgs/msg/PointCloud2"](
        header=header, height=1, width=len(data), fields=fields, is_bigendian=False,
        point_step=12, row_step=12 * len(data), data=data.view(np.uint8).ravel(), is_dense=True,
    )  # fmt: skip


def example_frames(count: int = 5, step_px: int = 8) -> list[NDArray]:
    """The example scene as a camera turning to its left sees it: each frame the depth image
    moved ``step_px`` pixels further right (the new columns without a reading)."""
    from itnet.scene.depth_io import png_to_depth

    depth = png_to_depth((EXAMPLES / "scene.png").read_bytes())
    frames = []
    for i in range(count):
        shifted = np.zeros_like(depth)
        shift = i * step_px
        shifted[:, shift:] = depth[:, : depth.shape[1] - shift]
        frames.append(shifted)
    return frames


EXAMPLES = Path(__file__).resolve().parents[1] / "itnet" / "examples"


def main() -> None:
    from itnet.scene.camera import parse_intrinsics

    path = EXAMPLES / "scene.bag"
    path.unlink(missing_ok=True)
    camera = parse_intrinsics(str(EXAMPLES / "scene_camera.json"))
    write_recording(path, "ros1", example_frames(), camera, Layout(period_ns=200_000_000),
                    compressed=True)  # fmt: skip
    print(f"{path}: {path.stat().st_size / 1e3:.0f} kB")


if __name__ == "__main__":
    main()
