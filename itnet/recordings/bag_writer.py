"""Writing the answers into a bag beside the recording's own topics: a copy of every message of
the input, and at each answered frame's log time its ``vision_msgs/Detection3DArray`` on
``<prefix>/detections`` and a ``geometry_msgs/PoseStamped`` per posed object on
``<prefix>/poses``.

The output's kind follows its name: ``*.bag`` a ROS 1 bag, anything else a ROS 2 bag folder
(sqlite3 storage where the input is a sqlite3 bag, else MCAP). Messages are
converted between ROS 1 and ROS 2 serialisation where the kinds differ. vision_msgs is no part
of the standard type stores: its ROS 2 (Humble and later) definitions are declared here, and
written into the bag with the connection, as ROS tools read them.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from itnet.recordings.bag import RecordingError, one_line
from itnet.recordings.ros_answer import DETECTIONS, POSE_STAMPED

VISION_MSGS = {
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n"
    ),
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": (
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
        "vision_msgs/BoundingBox3D bbox\nstring id\n"
    ),
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n",
}


@dataclass(frozen=True)
class Answer:
    """What to write for one frame: its log time (ns) in the recording, its Detection3DArray
    and PoseStamped messages as dicts (``itnet.recordings.ros_answer``)."""

    log_time_ns: int
    detections: dict[str, Any]
    poses: list[dict[str, Any]]


def typestore_with_vision_msgs(ros1: bool) -> Any:
    """A type store (ROS 1 Noetic's or the latest ROS 2's) that knows vision_msgs."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    types: dict[str, Any] = {}
    for name, text in VISION_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def build(store: Any, msgtype: str, value: dict[str, Any]) -> Any:
    """A message of ``msgtype`` from a dict of its fields (missing fields: zero, empty; numeric
    arrays as numpy arrays, as rosbags serialises them)."""
    from rosbags.typesys.base import Nodetype

    cls = store.types[msgtype]
    _, fields = store.fielddefs[msgtype]
    kwargs = {}
    for name, (kind, detail) in fields:
        given = value.get(name)
        if kind == Nodetype.NAME:
            kwargs[name] = build(store, detail, given or {})
        elif kind == Nodetype.BASE:
            kwargs[name] = _base(detail[0], given)
        else:
            (item_kind, item), _ = detail
            items = list(given or [])
            if item_kind == Nodetype.NAME:
                kwargs[name] = [build(store, item, v) for v in items]
            elif item[0] == "string":
                kwargs[name] = [str(v) for v in items]
            else:
                size = detail[1] if kind == Nodetype.ARRAY else len(items)
                kwargs[name] = np.asarray(items or np.zeros(size), dtype=_NUMPY[item[0]])
    return cls(**kwargs)


_NUMPY = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}  # fmt: skip


def _base(kind: str, given: Any) -> Any:
    if kind == "string":
        return "" if given is None else str(given)
    if kind == "bool":
        return bool(given)
    if kind.startswith("float"):
        return 0.0 if given is None else float(given)
    return 0 if given is None else int(given)


def write_answers(recording_path: Path, output: Path, answers: Iterable[Answer],
                  prefix: str = "/itnet") -> int:  # fmt: skip
    """Write the recording's messages and the answers (in log-time order) into ``output``;
    returns how many answer messages were written. RecordingError where it cannot be written."""
    from itnet.recordings.bag import open_recording

    queue = sorted(answers, key=lambda a: a.log_time_ns)
    ros1_out = output.suffix.lower() == ".bag"
    store = typestore_with_vision_msgs(ros1_out)
    if output.exists():
        shutil.rmtree(output) if output.is_dir() else output.unlink()
    try:
        with open_recording(recording_path) as recording:
            reader = recording.reader
            writer = _writer(output, ros1_out, reader)
            with writer:
                return _merge(reader, writer, store, ros1_out, queue, prefix)
    except RecordingError:
        raise
    except Exception as err:  # rosbags' writer errors, OSError
        raise RecordingError(f"{output}: cannot write the bag: {one_line(err)}") from None


def _writer(output: Path, ros1_out: bool, reader: Any) -> Any:
    if ros1_out:
        from rosbags.rosbag1 import Writer as Ros1Writer

        return Ros1Writer(output)
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Ros2Writer

    sqlite = any(
        "sqlite" in type(getattr(r, "storage", None)).__name__.lower() for r in reader.readers
    )
    plugin = StoragePlugin.SQLITE3 if sqlite else StoragePlugin.MCAP
    return Ros2Writer(output, version=9, storage_plugin=plugin)


def _merge(reader: Any, writer: Any, store: Any, ros1_out: bool, queue: list[Answer],
           prefix: str) -> int:  # fmt: skip
    ros1_in = not reader.is2
    copies = {}
    for c in reader.connections:
        if (c.topic, c.msgtype) in copies:
            continue
        copies[(c.topic, c.msgtype)] = writer.add_connection(
            c.topic, c.msgtype, typestore=reader.typestore
        )
    detections = writer.add_connection(f"{prefix}/detections", DETECTIONS, typestore=store)
    poses = writer.add_connection(f"{prefix}/poses", POSE_STAMPED, typestore=store)
    written = 0

    def flush(until: int | None) -> None:
        nonlocal written
        while queue and (until is None or queue[0].log_time_ns <= until):
            answer = queue.pop(0)
            writer.write(detections, answer.log_time_ns,
                         _serialise(store, DETECTIONS, answer.detections, ros1_out))  # fmt: skip
            for pose in answer.poses:
                writer.write(poses, answer.log_time_ns,
                             _serialise(store, POSE_STAMPED, pose, ros1_out))  # fmt: skip
            written += 1 + len(answer.poses)

    for connection, timestamp, raw in reader.messages():
        flush(timestamp - 1)
        data = raw
        if ros1_in != ros1_out:
            convert = reader.typestore.ros1_to_cdr if ros1_in else reader.typestore.cdr_to_ros1
            data = convert(raw, connection.msgtype)
        writer.write(copies[(connection.topic, connection.msgtype)], timestamp, data)
        flush(timestamp)
    flush(None)
    return written


def _serialise(store: Any, msgtype: str, value: dict[str, Any], ros1: bool) -> bytes:
    message = build(store, msgtype, value)
    return bytes(
        store.serialize_ros1(message, msgtype) if ros1 else store.serialize_cdr(message, msgtype)
    )
