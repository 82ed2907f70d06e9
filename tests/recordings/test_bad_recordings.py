"""Bad recordings: cut short, without a depth or camera-info topic, an encoding we do not read,
an uncalibrated camera, stamps out of order, no bag at all. Each is one line naming the topic
and the problem, exit 2, and the frames that could be read are still answered."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from benchmarks.recording import DEPTH_TOPIC, INFO_TOPIC, Layout, write_recording
from itnet.cli import app
from itnet.recordings import FrameError, RecordingError, Selection, open_recording
from itnet.scene.camera import parse_intrinsics
from itnet.scene.depth_io import png_to_depth

pytest.importorskip("rosbags")
EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"
CAMERA = parse_intrinsics(str(EXAMPLES / "scene_camera.json"))
runner = CliRunner()


def depth() -> np.ndarray:
    return png_to_depth((EXAMPLES / "scene.png").read_bytes())


def run(*args: str) -> tuple[int, list[dict], list[str]]:
    """Exit code, the JSON rows printed, the error lines."""
    result = runner.invoke(app, ["scene", *args, "--json", "--no-indices", "--budget-ms", "2000"])
    rows = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    return result.exit_code, rows, errors


def test_a_ros1_bag_cut_short_answers_the_frames_it_still_holds(tmp_path: Path) -> None:
    # 12 frames of 150 kB: the writer's chunks of about 1 MB hold 7 of them, and the cut takes
    # the second chunk and the index
    whole = write_recording(tmp_path / "whole.bag", "ros1", [depth()] * 12, CAMERA)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(whole.read_bytes()[: int(whole.stat().st_size * 0.75)])
    code, rows, errors = run(str(cut), "--every", "3")
    assert code == 2
    assert [r["frame"] for r in rows] == [0, 3, 6]
    assert all(len(r["objects"]) == 3 for r in rows)
    assert len(errors) == 1 and "index is missing or damaged" in errors[0] and str(cut) in errors[0]


@pytest.mark.parametrize("kind", ["mcap", "sqlite3"])
def test_a_ros2_bag_cut_short_is_one_line(kind: str, tmp_path: Path) -> None:
    folder = write_recording(tmp_path / "rec", kind, [depth()] * 2, CAMERA)
    storage = next(p for p in folder.iterdir() if p.suffix in (".mcap", ".db3"))
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
    with pytest.raises(RecordingError, match="not a readable ROS bag"), open_recording(folder):
        pass


def frames(bag: Path, **selection: object) -> list:
    """Every item ``Recording.frames`` gives (frames and frame errors)."""
    with open_recording(bag) as recording:
        return list(recording.frames(Selection(**selection)))  # type: ignore[arg-type]


def test_no_camera_info_asks_for_intrinsics_and_takes_them(tmp_path: Path) -> None:
    bag = write_recording(
        tmp_path / "rec.bag", "ros1", [depth()], CAMERA, Layout(camera_info=False)
    )
    code, rows, errors = run(str(bag))
    assert code == 2 and rows == []
    assert errors == [f"error: {bag}: {DEPTH_TOPIC}: no sensor_msgs/CameraInfo topic gives its "
                      "intrinsics; give them with --intrinsics"]  # fmt: skip
    code, rows, errors = run(str(bag), "--intrinsics", str(EXAMPLES / "scene_camera.json"))
    assert code == 0 and len(rows) == 1 and len(rows[0]["objects"]) == 3


def test_an_uncalibrated_camera_is_named(tmp_path: Path) -> None:
    bag = write_recording(tmp_path / "rec.bag", "ros1", [depth()], CAMERA, Layout(calibrated=False))
    with pytest.raises(RecordingError, match=f"{INFO_TOPIC}: no intrinsics: .*uncalibrated"):
        frames(bag)


def test_no_depth_topic_and_an_encoding_we_do_not_read(tmp_path: Path) -> None:
    bag = write_recording(tmp_path / "rec.bag", "ros1", [depth()], CAMERA, Layout(encoding="mono8"))
    with pytest.raises(
        RecordingError, match=f"no depth image .*its images are {DEPTH_TOPIC}, none"
    ):
        frames(bag)
    (error,) = frames(bag, topic=DEPTH_TOPIC)
    assert isinstance(error, FrameError) and (error.topic, error.index) == (DEPTH_TOPIC, 0)
    assert error.reason == "encoding 'mono8' is not a depth encoding (16UC1, mono16, 32FC1, 64FC1)"
    with pytest.raises(RecordingError, match=f"{INFO_TOPIC}: a sensor_msgs/CameraInfo topic"):
        frames(bag, topic=INFO_TOPIC)
    with pytest.raises(RecordingError, match="/nowhere: no such topic"):
        frames(bag, topic="/nowhere")
    with pytest.raises(RecordingError, match="/nowhere: no sensor_msgs/CameraInfo topic"):
        frames(bag, topic=DEPTH_TOPIC, camera_info="/nowhere")


def test_stamps_out_of_order_are_reported_and_the_rest_answered(tmp_path: Path) -> None:
    start = Layout().start_ns
    stamps = [start, start + 2 * 10**8, start + 10**8]  # the third stamped before the second
    bag = write_recording(tmp_path / "rec.bag", "ros1", [depth()] * 3, CAMERA, stamps_ns=stamps)
    code, rows, errors = run(str(bag))
    assert code == 2
    assert [r["frame"] for r in rows] == [0, 1]
    assert errors == [f"error: {bag}: {DEPTH_TOPIC} frame 2: timestamps out of order: its stamp "
                      "is earlier than the frame before"]  # fmt: skip


def test_what_is_no_bag_is_one_line_and_other_files_are_still_answered(tmp_path: Path) -> None:
    fake = tmp_path / "fake.bag"
    fake.write_bytes(b"#ROSBAG V2.0\nnonsense")
    code, rows, errors = run(str(fake), str(EXAMPLES / "scene.png"), "--intrinsics",
                             str(EXAMPLES / "scene_camera.json"))  # fmt: skip
    assert code == 2 and len(rows) == 1 and len(rows[0]["objects"]) == 3
    assert len(errors) == 1 and errors[0].startswith(f"error: {fake}: not a readable ROS bag")
    result = runner.invoke(app, ["scene", str(tmp_path / "missing.bag")])
    assert result.exit_code == 2 and "no such file or folder" in result.stderr


def test_frame_options_are_checked() -> None:
    result = runner.invoke(app, ["scene", "x.bag", "--start", "5", "--end", "1"])
    assert result.exit_code == 2 and "before the start" in result.output
    result = runner.invoke(app, ["scene", "x.bag", "--every", "0"])
    assert result.exit_code == 2
    result = runner.invoke(app, ["scene", "x.bag", "--format", "xml"])
    assert result.exit_code == 2 and "--format" in result.output
