"""Recordings in ``itnet scene`` and ``itnet pose``: the options that choose a bag's frames,
declared once (``itnet batch scene`` takes them too), and the loops that answer a bag's frames
and print them, write them into a bag and log them for Rerun."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    from itnet.recordings import Selection
    from itnet.recordings.rerun_log import RerunLog

FORMATS = ("text", "json", "ros")
TOPIC = typer.Option(
    None,
    help="A bag's frame topic: a depth image (sensor_msgs/Image 16UC1, mono16 or 32FC1) or a "
    "sensor_msgs/PointCloud2 (default: the one of these the bag has).",
)
CAMERA_INFO = typer.Option(
    None,
    "--camera-info",
    help="A bag's sensor_msgs/CameraInfo topic for the depth images (default: the one beside "
    "the image topic).",
)
EVERY = typer.Option(1, min=1, help="A bag: answer every N-th frame of the topic.")
START = typer.Option(None, "--start", help="A bag: from this many seconds after its start.")
END = typer.Option(None, "--end", help="A bag: up to this many seconds after its start.")


def selection(topic: str | None, camera_info: str | None, every: int, start: float | None,
              end: float | None) -> Selection:  # fmt: skip
    """The frame options -> a Selection, or a usage error."""
    from itnet.recordings import RecordingError, Selection

    try:
        return Selection(topic, camera_info, every, start, end)
    except RecordingError as err:
        raise typer.BadParameter(str(err)) from None


def require_rosbags() -> None:
    """Exit 2 with the install line where rosbags is missing."""
    try:
        import rosbags  # noqa: F401
    except ImportError as err:
        typer.echo(f"error: reading bags needs rosbags (pip install 'itnet[recordings]'): {err}",
                   err=True)  # fmt: skip
        raise typer.Exit(2) from None


@dataclass
class SceneOutputs:
    """Where a recording's answers go besides standard output: a bag, a Rerun log."""

    output_bag: Path | None = None
    rerun: RerunLog | None = None


def open_rerun(path: Path | None, viewer: bool) -> RerunLog | None:
    """The Rerun log asked for (a file, or a spawned viewer), or None."""
    if path is None and not viewer:
        return None
    from itnet.recordings.rerun_log import RerunLog, RerunUnavailable

    try:
        return RerunLog(path)
    except RerunUnavailable as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None


def scene_recording(path: Path, chosen: Selection, arguments: dict[str, Any], catalog: Any,
                    fmt: str, indices: bool, outputs: SceneOutputs) -> bool:  # fmt: skip
    """Answer, print and write every selected frame of one recording; False where a frame (or
    the recording) could not be used, each such problem printed as one line."""
    from itnet.recordings import RecordingError, describe, scene_answers, write_answers
    from itnet.recordings.answer import SceneAnswer, scene_finder

    find = scene_finder(catalog, arguments)
    ok, answers = True, []
    try:
        for item in scene_answers(path, chosen, find, arguments["intrinsics"],
                                  arguments["depth_scale"]):  # fmt: skip
            if not isinstance(item, SceneAnswer):
                typer.echo(f"error: {describe(path, item)}", err=True)
                ok = False
                continue
            print_scene(item, fmt, indices)
            if outputs.rerun is not None:
                outputs.rerun.log_frame(item.frame.index, item.frame.stamp_ns, item.scene.points,
                                        item.objects, item.object_rows())  # fmt: skip
            if outputs.output_bag is not None:
                answers.append(item.answer())
        if outputs.output_bag is not None:
            write_answers(path, outputs.output_bag, answers)
    except RecordingError as err:
        typer.echo(f"error: {path}: {err}", err=True)
        return False
    return ok


def print_scene(item: Any, fmt: str, indices: bool) -> None:
    """One answered frame on standard output, as ``fmt`` says."""
    if fmt == "json":
        typer.echo(json.dumps(item.row(indices)))
    elif fmt == "ros":
        typer.echo(json.dumps(item.detections()))
    else:
        stamp = item.frame.stamp_ns * 1e-9
        names = ", ".join(f"{o.category} ({o.probability:.2f})" for o in item.result.objects)
        typer.echo(f"{item.path} {item.frame.topic} frame {item.frame.index} at {stamp:.3f} s: "
                   f"{len(item.result.objects)} object(s) in {item.result.elapsed_ms:.0f} ms"
                   f"{': ' + names if names else ''}")  # fmt: skip


def pose_recording(path: Path, chosen: Selection, start: Any, as_json: bool) -> bool:
    """Pose every selected PointCloud2 of one recording (``start``: a cloud -> its run) and
    print each; False where one (or the recording) could not be used."""
    from itnet.pose.errors import PoseError
    from itnet.recordings import RecordingError, describe, pose_answers

    def pose(points: Any) -> dict[str, Any]:
        run = start(points)
        run.run_to_end()
        return run.result()

    ok = True
    try:
        for item in pose_answers(path, chosen, pose):
            if not isinstance(item, tuple):
                typer.echo(f"error: {describe(path, item)}", err=True)
                ok = False
                continue
            frame, row = item
            if as_json:
                typer.echo(json.dumps(row))
            else:
                typer.echo(f"{path} {frame.topic} frame {frame.index}: {row['iterations']} "
                           f"iterations in {row['elapsed_ms']:.1f} ms, translation "
                           f"{[round(v, 4) for v in row['translation']]}")  # fmt: skip
    except (RecordingError, PoseError) as err:
        typer.echo(f"error: {path}: {err}", err=True)
        return False
    return ok
