"""A scene's answer shaped as the messages a robot reads: ``vision_msgs/Detection3DArray`` and a
``geometry_msgs/PoseStamped`` per posed object, as plain dicts with the messages' field names
(ROS 2 Humble and later; ``itnet.recordings.bag_writer`` turns them into messages).

Frames. Everything is in the camera's optical frame, the header's ``frame_id`` (x right, y
down, z ahead). An object's pose is ``T_camera_from_canonical``: the position of its category's
canonical origin (the centre of its bounding box) and the orientation of its canonical axes
(x its right, y up, z its front; ``docs/recordings.md``), the inverse of the scene's
``T_canonical_from_input``. The box is the object's oriented box (``bbox.center`` its centre
and turn, ``bbox.size`` its extent along its own x, y, z). An object without a pose (no model,
or no time) gives its box's centre and turn as its pose, with the covariance's diagonal at -1
(unknown), as REP 145 marks a value not measured.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from itnet.geometry import invert_rigid, matrix_to_quat_wxyz

UNKNOWN_CLASS = "unknown"
DETECTIONS = "vision_msgs/msg/Detection3DArray"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"


def detection_array(header: dict[str, Any], objects: list[dict[str, Any]]) -> dict[str, Any]:
    """A frame's header and its objects (``SceneObject.as_dict``) -> Detection3DArray: one
    Detection3D an object, ``id`` its place in the answer ("0", "1", ...), one hypothesis (the
    category and its probability) with the object's pose."""
    return {
        "header": header,
        "detections": [_detection(header, i, obj) for i, obj in enumerate(objects)],
    }


def poses_stamped(header: dict[str, Any], objects: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A PoseStamped for each posed object of the frame, in the objects' order."""
    return [
        {"header": header, "pose": object_pose(obj)}
        for obj in objects
        if obj.get("T_canonical_from_input") is not None
    ]


def object_pose(obj: dict[str, Any]) -> dict[str, Any]:
    """The object's ``geometry_msgs/Pose`` in the camera frame (its box's where it has no pose)."""
    if obj.get("T_canonical_from_input") is not None:
        pose = invert_rigid(np.asarray(obj["T_canonical_from_input"], dtype=np.float64))
        return _pose(pose[:3, 3], pose[:3, :3])
    box = obj["box"]
    return _pose(np.asarray(box["center"]), np.asarray(box["R_camera_from_box"]))


def _detection(header: dict[str, Any], index: int, obj: dict[str, Any]) -> dict[str, Any]:
    posed = obj.get("T_canonical_from_input") is not None
    box = obj["box"]
    covariance = np.zeros(36) if posed else -np.eye(6).ravel()
    return {
        "header": header,
        "results": [
            {
                "hypothesis": {
                    "class_id": obj.get("category") or UNKNOWN_CLASS,
                    "score": float(obj.get("category_probability", 0.0)),
                },
                "pose": {"pose": object_pose(obj), "covariance": covariance.tolist()},
            }
        ],
        "bbox": {
            "center": _pose(np.asarray(box["center"]), np.asarray(box["R_camera_from_box"])),
            "size": dict(zip("xyz", map(float, box["size"]))),
        },
        "id": str(index),
    }


def _pose(position: np.ndarray, rotation: np.ndarray) -> dict[str, Any]:
    w, x, y, z = (float(v) for v in matrix_to_quat_wxyz(rotation))
    return {
        "position": dict(zip("xyz", map(float, position))),
        "orientation": {"x": x, "y": y, "z": z, "w": w},
    }
