"""A recording's frames answered one after another: each depth frame's (or cloud's) objects with
its header, or each object cloud's pose, as the JSON rows ``itnet scene`` / ``itnet pose`` print
and the ROS messages ``--format ros`` and ``--output-bag`` give.

    for item in scene_answers(Path("recording.bag"), Selection(every=3), find):
        if isinstance(item, FrameError): ...
        else: item.row(indices=False), item.detections()

``find`` is the scene pipeline with its options bound (``find_objects``), given a SceneInput and
the time its frame was read; each frame's budget starts when its message is read.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from itnet.recordings.bag import Frame, FrameError, Selection, open_recording
from itnet.recordings.bag_writer import Answer
from itnet.recordings.ros_answer import detection_array, poses_stamped
from itnet.scene.camera import Intrinsics, SceneInputError
from itnet.scene.inputs import SceneInput, SceneLimits, from_cloud, from_depth
from itnet.scene.result import SceneResult

FindObjects = Callable[[SceneInput, float], SceneResult]


def scene_finder(catalog: Any, arguments: dict[str, Any]) -> FindObjects:
    """``find_objects`` with ``catalog`` and the scene options bound (``arguments``: its keywords
    as ``itnet.commands.scene.scene_arguments`` makes them; the intrinsics and depth scale are
    the recording's, and are left out)."""
    from itnet.scene import find_objects

    keywords = {k: v for k, v in arguments.items() if k not in ("intrinsics", "depth_scale")}

    def find(scene: SceneInput, started: float) -> SceneResult:
        return find_objects(scene, catalog=catalog, started=started, **keywords)

    return find


@dataclass
class SceneAnswer:
    """One frame and what was found in it: the scene's points (SceneInput) and its result."""

    path: Path
    frame: Frame
    scene: SceneInput
    result: SceneResult

    @cached_property
    def objects(self) -> list[dict[str, Any]]:
        """Each object's JSON form without its indices, made once for every output."""
        return [o.as_dict(False) for o in self.result.objects]

    def row(self, indices: bool = True) -> dict[str, Any]:
        """The JSON row: ``file``, ``topic``, ``frame`` (its place on the topic), ``header``, and
        the scene's answer as ``itnet scene --json`` gives it."""
        return {**self.frame.where(self.path), **self.result.as_dict(indices)}

    def detections(self) -> dict[str, Any]:
        """The frame's vision_msgs/Detection3DArray (as a dict)."""
        return detection_array(self.frame.header(), self.objects)

    def answer(self) -> Answer:
        """What ``--output-bag`` writes for the frame."""
        header = self.frame.header()
        return Answer(self.frame.log_time_ns, detection_array(header, self.objects),
                      poses_stamped(header, self.objects))  # fmt: skip

    def object_rows(self) -> list[NDArray[np.int64]]:
        """Each object's rows into ``scene.points`` (its indices are pixels or cloud rows)."""
        return [np.searchsorted(self.scene.indices, o.indices) for o in self.result.objects]


def scene_answers(
    path: Path, selection: Selection, find: FindObjects, intrinsics: Intrinsics | None = None,
    depth_scale: float | None = None, limits: SceneLimits = SceneLimits(),
) -> Iterator[SceneAnswer | FrameError]:  # fmt: skip
    """Every selected frame of the recording, answered. ``intrinsics``: the camera's where the
    recording has no camera info. RecordingError where the recording cannot be read at all."""
    for frame in _frames(path, selection, intrinsics):
        if isinstance(frame, FrameError):
            yield frame
            continue
        started = time.perf_counter()
        try:
            scene = (
                from_cloud(frame.points, limits)
                if frame.points is not None
                else from_depth(frame.depth, frame.intrinsics, depth_scale, limits)  # type: ignore[arg-type]
            )
            yield SceneAnswer(path, frame, scene, find(scene, started))
        except SceneInputError as err:
            yield FrameError(frame.topic, frame.index, str(err))


def pose_answers(
    path: Path, selection: Selection, pose: Callable[[NDArray[np.float64]], dict[str, Any]]
) -> Iterator[tuple[Frame, dict[str, Any]] | FrameError]:
    """Every selected PointCloud2 of the recording (an object's cloud), posed: (frame, its
    ``itnet pose --json`` row with ``topic``, ``frame`` and ``header``). ``pose``: a cloud
    (N, 3) -> its pose reply; its ValueError (a cloud that cannot be posed) becomes a FrameError."""
    for frame in _frames(path, replace(selection, clouds_only=True)):
        if isinstance(frame, FrameError):
            yield frame
            continue
        assert frame.points is not None  # a cloud topic's frames are clouds
        points = frame.points[np.isfinite(frame.points).all(axis=1)]
        try:
            reply = pose(points)
        except ValueError as err:
            yield FrameError(frame.topic, frame.index, str(err))
            continue
        yield frame, {**frame.where(path), **reply}


def _frames(path: Path, selection: Selection,
            intrinsics: Intrinsics | None = None) -> Iterator[Frame | FrameError]:  # fmt: skip
    """The recording's selected frames, after a FrameError without a topic where it was read
    without its index."""
    with open_recording(path) as recording:
        if recording.recovered:
            yield FrameError("", -1, recording.recovered)
        yield from recording.frames(selection, intrinsics)


def describe(path: Path, error: FrameError) -> str:
    """A frame's error as the one line the CLI prints (a whole recording's where it has no
    topic: read without its index)."""
    if not error.topic:
        return f"{path}: {error.reason}"
    return f"{path}: {error.topic} frame {error.index}: {error.reason}"
