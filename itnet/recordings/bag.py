"""Reading a robot recording: the depth frames (or clouds) of a ROS 1 bag, or a ROS 2 bag in
sqlite3 or MCAP storage, each with its header and its camera's intrinsics.

    with open_recording(Path("recording.bag")) as recording:
        for frame in recording.frames(Selection(every=5)):
            if isinstance(frame, FrameError): ...      # one frame that cannot be used
            else: frame.depth, frame.intrinsics, frame.stamp_ns, frame.frame_id

Read with ``rosbags`` (pure Python, no ROS installation). The topics are found by type: the
``sensor_msgs/Image`` topic of a depth encoding (``16UC1``/``mono16`` depth units, ``32FC1``
metres), or the ``sensor_msgs/CompressedImage`` of image_transport's ``compressedDepth``, and
the ``sensor_msgs/CameraInfo`` beside it, else a ``sensor_msgs/PointCloud2`` topic;
``Selection.topic`` / ``camera_info`` choose where there are several. A frame takes the last
camera info logged before it (the first of the recording where none came before: RealSense
recordings log it once). Problems with the recording as a whole raise RecordingError; problems
with one frame are yielded as FrameError, and reading goes on.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from itnet.recordings.decode import (
    DEPTH_ENCODINGS,
    DecodeError,
    camera_intrinsics,
    cloud_points,
    compressed_depth,
    depth_image,
    header_of,
    is_compressed_depth,
)
from itnet.scene.camera import Intrinsics

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
FRAME_TYPES = (IMAGE, COMPRESSED, POINT_CLOUD)
ROS1_SUFFIX = ".bag"
ROS2_FILE_SUFFIXES = (".db3", ".mcap")
RECORDING_SUFFIXES = (ROS1_SUFFIX, *ROS2_FILE_SUFFIXES)


class RecordingError(ValueError):
    """A recording that cannot be read at all (not a bag, no usable topic); one line, naming the
    topic where one is at fault."""


def is_recording(path: Path) -> bool:
    """Whether ``path`` is a ROS bag: a ``.bag`` file (ROS 1), a ``.db3`` / ``.mcap`` file or a
    folder with ``metadata.yaml`` (ROS 2)."""
    suffix = path.suffix.lower()
    return suffix in (ROS1_SUFFIX, *ROS2_FILE_SUFFIXES) or (path / "metadata.yaml").is_file()


@dataclass(frozen=True)
class Selection:
    """Which frames of a recording to read: the frame topic (default: found by type), the
    camera-info topic (default: the one beside it), every ``every``-th frame of the topic, those
    logged from ``start_s`` to ``end_s`` seconds after the recording's start."""

    topic: str | None = None
    camera_info: str | None = None
    every: int = 1
    start_s: float | None = None
    end_s: float | None = None
    clouds_only: bool = False  # only a PointCloud2 topic will do (poses of object clouds)

    def __post_init__(self) -> None:
        if self.every < 1:
            raise RecordingError(f"every must be at least 1, got {self.every}")
        if self.start_s is not None and self.end_s is not None and self.end_s < self.start_s:
            raise RecordingError(
                f"the end ({self.end_s:g} s) is before the start ({self.start_s:g} s)"
            )


@dataclass(frozen=True)
class Frame:
    """One frame: a depth image (H, W) (uint16 depth units or float metres) with its camera's
    intrinsics, or a cloud (N, 3) in ``frame_id``'s frame; ``index``: its place on the topic,
    ``stamp_ns`` its header's stamp, ``log_time_ns`` when the recording logged it."""

    topic: str
    index: int
    stamp_ns: int
    frame_id: str
    log_time_ns: int
    depth: NDArray | None = None
    intrinsics: Intrinsics | None = None
    points: NDArray | None = None

    def header(self) -> dict[str, Any]:
        """The frame's ROS header: ``stamp`` {sec, nanosec} and ``frame_id``."""
        sec, nanosec = divmod(self.stamp_ns, 1_000_000_000)
        return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": self.frame_id}

    def where(self, path: Path) -> dict[str, Any]:
        """The fields that place the frame's row: ``file``, ``topic``, ``frame``, ``header``."""
        return {
            "file": str(path),
            "topic": self.topic,
            "frame": self.index,
            "header": self.header(),
        }


@dataclass(frozen=True)
class FrameError:
    """A frame that could not be used: where it is and why (one line); with no topic (index -1),
    a problem of the whole recording that did not stop its reading."""

    topic: str
    index: int
    reason: str


class Recording:
    """An open recording (``open_recording``): its topics, and its frames one at a time."""

    def __init__(self, path: Path, reader: Any, recovered: str = "") -> None:
        self.path = path
        self.reader = reader
        self.topics: dict[str, str] = {c.topic: c.msgtype for c in reader.connections}
        self.recovered = recovered  # why the recording was read without its index, where it was

    def frames(self, selection: Selection = Selection(),
               intrinsics: Intrinsics | None = None) -> Iterator[Frame | FrameError]:  # fmt: skip
        """Every selected frame in the order it was logged. ``intrinsics``: the camera's, where
        the recording has no camera info (else the camera info's are used)."""
        topic = self.frame_topic(selection)
        is_image = self.topics[topic] in (IMAGE, COMPRESSED)
        info_topic = self.info_topic(topic, selection) if is_image and intrinsics is None else None
        camera = self._first_intrinsics(info_topic) if info_topic else intrinsics
        wanted = [c for c in self.reader.connections if c.topic in (topic, info_topic)]
        start, stop = self._time_window(selection)
        index, last_stamp = -1, None
        messages = self.reader.messages(connections=wanted, start=start, stop=stop)
        try:
            for connection, log_time, raw in messages:
                if connection.topic == info_topic:
                    with contextlib.suppress(DecodeError):
                        camera = camera_intrinsics(self._message(raw, connection))
                    continue
                index += 1
                if index % selection.every:
                    continue
                frame = self._frame(topic, index, log_time, raw, connection, camera, is_image)
                if isinstance(frame, Frame):
                    if last_stamp is not None and frame.stamp_ns < last_stamp:
                        yield FrameError(topic, index, "timestamps out of order: its stamp is "
                                         "earlier than the frame before")  # fmt: skip
                        continue
                    last_stamp = frame.stamp_ns
                yield frame
        except (
            Exception
        ) as err:  # rosbags raises its own errors, and struct/zlib ones, on a cut file
            if isinstance(err, RecordingError):
                raise
            yield FrameError(topic, index + 1, f"the recording ends early, unreadable from here "
                             f"(truncated?): {one_line(err)}")  # fmt: skip

    def frame_topic(self, selection: Selection) -> str:
        """The topic the frames come from: the one asked for, else found by type."""
        types = (POINT_CLOUD,) if selection.clouds_only else FRAME_TYPES
        if selection.topic is not None:
            kind = self.topics.get(selection.topic)
            if kind is None:
                raise RecordingError(f"{selection.topic}: no such topic (topics: {self._listed()})")
            if kind not in types:
                raise RecordingError(
                    f"{selection.topic}: a {kind.replace('/msg/', '/')} topic; a frame topic is a "
                    f"{' or '.join(t.replace('/msg/', '/') for t in types)}"
                )
            return selection.topic
        kinds = () if selection.clouds_only else (IMAGE, COMPRESSED)
        images = [t for t, k in self.topics.items() if k in kinds]
        depth = [t for t in images if self._first_encoding(t) in DEPTH_ENCODINGS]
        clouds = [t for t, k in self.topics.items() if k == POINT_CLOUD]
        for found in (depth, clouds):
            if len(found) == 1:
                return found[0]
            if len(found) > 1:
                raise RecordingError(
                    f"several frame topics ({', '.join(found)}): choose one with --topic"
                )
        what = "sensor_msgs/PointCloud2" if selection.clouds_only else (
            "depth image (sensor_msgs/Image, " + "/".join(DEPTH_ENCODINGS) + "; compressedDepth) or PointCloud2")  # fmt: skip
        others = f"; its images are {', '.join(images)}, none of a depth encoding" if images else ""
        raise RecordingError(f"no {what} topic (topics: {self._listed()}){others}")

    def info_topic(self, topic: str, selection: Selection) -> str:
        """The camera-info topic for the depth image topic: the one asked for, else the one
        whose namespace shares most with the image's."""
        infos = [t for t, k in self.topics.items() if k == CAMERA_INFO]
        if selection.camera_info is not None:
            if self.topics.get(selection.camera_info) != CAMERA_INFO:
                raise RecordingError(f"{selection.camera_info}: no sensor_msgs/CameraInfo topic of "
                                     f"that name (camera info topics: {', '.join(infos) or 'none'})")  # fmt: skip
            return selection.camera_info
        if not infos:
            raise RecordingError(f"{topic}: no sensor_msgs/CameraInfo topic gives its intrinsics; "
                                 "give them with --intrinsics")  # fmt: skip
        return max(infos, key=lambda t: (shared_prefix(t, topic), -len(t)))

    def _first_intrinsics(self, info_topic: str) -> Intrinsics:
        connections = [c for c in self.reader.connections if c.topic == info_topic]
        problem = "it logged no message"
        for connection, _, raw in self.reader.messages(connections=connections):
            try:
                return camera_intrinsics(self._message(raw, connection))
            except DecodeError as err:
                problem = str(err)
        raise RecordingError(f"{info_topic}: no intrinsics: {problem}; give them with --intrinsics")

    def _first_encoding(self, topic: str) -> str | None:
        connections = [c for c in self.reader.connections if c.topic == topic]
        for connection, _, raw in self.reader.messages(connections=connections):
            try:
                message = self._message(raw, connection)
            except Exception:  # a message that does not deserialise has no encoding
                return None
            if connection.msgtype == COMPRESSED:  # compressedDepth: '16UC1; compressedDepth png'
                return (
                    str(message.format).split(";")[0].strip()
                    if is_compressed_depth(message)
                    else None
                )
            return str(message.encoding)
        return None

    def _frame(self, topic: str, index: int, log_time: int, raw: bytes, connection: Any,
               camera: Intrinsics | None, is_image: bool) -> Frame | FrameError:  # fmt: skip
        try:
            message = self._message(raw, connection)
            stamp, frame_id = header_of(message)
            where = (topic, index, stamp, frame_id, log_time)
            if not is_image:
                return Frame(*where, points=cloud_points(message))
            depth = (
                compressed_depth(message)
                if connection.msgtype == COMPRESSED
                else depth_image(message)
            )
            return Frame(*where, depth=depth, intrinsics=camera)
        except DecodeError as err:
            return FrameError(topic, index, str(err))
        except Exception as err:  # a message its own type does not describe
            return FrameError(topic, index, f"the message does not deserialise: {one_line(err)}")

    def _message(self, raw: bytes, connection: Any) -> Any:
        return self.reader.deserialize(raw, connection.msgtype)

    def _time_window(self, selection: Selection) -> tuple[int | None, int | None]:
        begin = int(self.reader.start_time)
        start = None if selection.start_s is None else begin + int(selection.start_s * 1e9)
        stop = None if selection.end_s is None else begin + int(selection.end_s * 1e9) + 1
        return start, stop

    def _listed(self) -> str:
        return (
            ", ".join(f"{t} ({k.replace('/msg/', '/')})" for t, k in self.topics.items()) or "none"
        )


@contextlib.contextmanager
def open_recording(path: Path) -> Iterator[Recording]:
    """Open a ROS 1 or ROS 2 bag for reading. A ROS 1 bag whose index is missing or damaged (a
    recording cut short) is read in file order up to where it ends (``Recording.recovered``
    says so). RecordingError where it is no readable bag."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise RecordingError("no such file or folder")
    store = get_typestore(Stores.LATEST)
    recovered = ""
    try:
        reader = AnyReader([bag_root(path)], default_typestore=store)
        reader.open()
    except Exception as err:  # rosbags' own errors, and OSError, for what is no bag
        problem = one_line(err)
        if path.suffix.lower() != ROS1_SUFFIX or "index" not in problem.lower():
            raise RecordingError(f"not a readable ROS bag: {problem}") from None
        reader, recovered = _unindexed(path, store, problem)
    try:
        yield Recording(path, reader, recovered)
    finally:
        reader.close()


def _unindexed(path: Path, store: Any, problem: str) -> tuple[Any, str]:
    """An AnyReader over the readable part of a ROS 1 bag without a usable index."""
    from rosbags.highlevel import AnyReader

    from itnet.recordings.ros1_recovery import UnindexedRos1Reader

    reader = AnyReader([path], default_typestore=store)
    scanned = UnindexedRos1Reader(path)
    reader.readers = [scanned]  # type: ignore[assignment]
    try:
        reader.open()
    except Exception as err:
        raise RecordingError(f"not a readable ROS bag: {problem}; {one_line(err)}") from None
    if not scanned.message_count:
        reader.close()
        raise RecordingError(f"not a readable ROS bag: {problem}; no whole chunk of messages in it")
    end = f"; {scanned.end_note}" if scanned.end_note else ""
    return reader, f"its index is missing or damaged (cut short?): read in file order{end}"


def bag_root(path: Path) -> Path:
    """What rosbags opens: a ROS 1 bag file, or a ROS 2 bag's folder (the folder holding a
    ``.db3`` / ``.mcap`` file given, where it has its metadata.yaml)."""
    if path.suffix.lower() in ROS2_FILE_SUFFIXES and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return path


def shared_prefix(a: str, b: str) -> int:
    """How many leading topic name parts two topics share ('/camera/depth/x', '/camera/depth/y': 3)."""
    parts = 0
    for x, y in zip(a.split("/"), b.split("/")):
        if x != y:
            break
        parts += 1
    return parts


def one_line(err: BaseException) -> str:
    """An exception as one line: its type where its text is empty."""
    text = " ".join(str(err).split())
    return text or type(err).__name__
