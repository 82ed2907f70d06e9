"""Recordings through the CLI as a user runs them: bags built with rosbags (ROS 1, ROS 2 sqlite3,
ROS 2 MCAP) from the shipped example scene, answered frame by frame as ``itnet scene`` answers
the same frames, written back as a bag of Detection3DArray messages and logged for Rerun."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from benchmarks.recording import (
    CLOUD_TOPIC,
    DEPTH_TOPIC,
    FRAME_ID,
    Layout,
    write_clouds,
    write_recording,
)
from itnet.cli import app
from itnet.cloud_io import read_cloud
from itnet.geometry import invert_rigid, quat_wxyz_to_matrix, quat_xyzw_to_wxyz
from itnet.scene.camera import depth_to_cloud, parse_intrinsics
from itnet.scene.depth_io import png_to_depth

pytest.importorskip("rosbags")
EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"
CAMERA = EXAMPLES / "scene_camera.json"
BUDGET = ["--budget-ms", "3000"]  # every object its card's runs, on a slow machine too
runner = CliRunner()


def example_depth() -> np.ndarray:
    return png_to_depth((EXAMPLES / "scene.png").read_bytes())


def bag_path(tmp_path: Path, kind: str, name: str = "rec") -> Path:
    return tmp_path / (f"{name}.bag" if kind == "ros1" else name)


def lines(output: str) -> list[dict]:
    return [json.loads(line) for line in output.splitlines() if line.startswith("{")]


@pytest.fixture(scope="module")
def png_answer() -> dict:
    """``itnet scene`` on the example PNG itself."""
    result = runner.invoke(app, ["scene", str(EXAMPLES / "scene.png"), "--intrinsics", str(CAMERA),
                                 *BUDGET, "--json"])  # fmt: skip
    assert result.exit_code == 0, result.output
    return lines(result.stdout)[0]


def assert_same_objects(got: list[dict], expected: list[dict], exact: bool = True) -> None:
    """Same objects, named alike, the same points and boxes, poses within 0.5 degree and 5 mm
    (not ``exact``: depth that went through float32 metres, points and boxes within 1 %, 1 cm,
    poses within 4 degrees and 1 cm: a point that rounds into another voxel changes the seeded
    subsets the runs draw, and the pose moves within its own noise)."""
    assert [o["category"] for o in got] == [o["category"] for o in expected]
    for a, b in zip(got, expected):
        assert a["points"] == pytest.approx(b["points"], rel=0 if exact else 0.01)
        np.testing.assert_allclose(
            a["box"]["center"], b["box"]["center"], atol=1e-6 if exact else 1e-2
        )
        pa, pb = np.asarray(a["T_canonical_from_input"]), np.asarray(b["T_canonical_from_input"])
        cos = (np.trace(pa[:3, :3].T @ pb[:3, :3]) - 1) / 2
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < (0.5 if exact else 4.0)
        assert np.linalg.norm(invert_rigid(pa)[:3, 3] - invert_rigid(pb)[:3, 3]) < (
            5e-3 if exact else 1e-2
        )


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_a_bag_s_frames_are_answered_as_itnet_scene_answers_them(
    kind: str, tmp_path: Path, png_answer: dict
) -> None:
    """Depth frames with their CameraInfo, found by type: each frame's objects equal those of
    the same frame as a PNG, and its header is the frame's own."""
    bag = write_recording(bag_path(tmp_path, kind), kind, [example_depth()] * 2,
                          parse_intrinsics(str(CAMERA)))  # fmt: skip
    result = runner.invoke(app, ["scene", str(bag), *BUDGET, "--json", "--no-indices"])
    assert result.exit_code == 0, result.output
    rows = lines(result.stdout)
    assert [r["frame"] for r in rows] == [0, 1]
    start = Layout().start_ns
    for i, row in enumerate(rows):
        assert row["topic"] == DEPTH_TOPIC and row["file"] == str(bag)
        stamp = start + i * Layout().period_ns
        assert row["header"] == {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9},
                                 "frame_id": FRAME_ID}  # fmt: skip
        assert row["image_shape"] == png_answer["image_shape"]
        assert_same_objects(row["objects"], png_answer["objects"])


def test_float_metres_compressed_depth_and_a_cloud_topic_give_the_same_objects(
    tmp_path: Path, png_answer: dict
) -> None:
    """A 32FC1 depth topic (metres) and a compressedDepth one answer as 16UC1 does; a
    PointCloud2 topic of the frame's points answers as ``itnet scene`` on the same cloud file."""
    camera = parse_intrinsics(str(CAMERA))
    depth = example_depth()
    floats = write_recording(tmp_path / "f.bag", "ros1", [depth], camera, Layout(encoding="32FC1"))
    result = runner.invoke(app, ["scene", str(floats), *BUDGET, "--json", "--no-indices"])
    assert result.exit_code == 0, result.output
    assert_same_objects(lines(result.stdout)[0]["objects"], png_answer["objects"], exact=False)

    packed = write_recording(
        tmp_path / "p.bag", "ros1", [depth], camera, Layout(encoding="compressedDepth")
    )
    result = runner.invoke(app, ["scene", str(packed), *BUDGET, "--json", "--no-indices"])
    assert result.exit_code == 0, result.output
    row = lines(result.stdout)[0]
    assert row["topic"] == DEPTH_TOPIC + "/compressedDepth"
    assert_same_objects(row["objects"], png_answer["objects"])

    clouds = write_recording(
        tmp_path / "c", "mcap", [depth], camera, Layout(depth=False, cloud=True)
    )
    points, _ = depth_to_cloud(depth / 1000.0, camera)
    np.save(tmp_path / "cloud.npy", points.astype(np.float32))
    from_bag = runner.invoke(app, ["scene", str(clouds), *BUDGET, "--json", "--no-indices"])
    from_file = runner.invoke(app, ["scene", str(tmp_path / "cloud.npy"), *BUDGET, "--json",
                                    "--no-indices"])  # fmt: skip
    assert from_bag.exit_code == 0 and from_file.exit_code == 0, from_bag.output + from_file.output
    row = lines(from_bag.stdout)[0]
    assert row["topic"] == CLOUD_TOPIC and row["image_shape"] is None
    assert_same_objects(row["objects"], lines(from_file.stdout)[0]["objects"])
    assert sorted(o["category"] for o in row["objects"]) == ["chair", "night_stand", "toilet"]


@pytest.mark.parametrize(("kind", "out_name"), [("ros1", "out.bag"), ("mcap", "out_bag")])
def test_detections_are_written_into_a_bag_beside_the_recording(
    kind: str, out_name: str, tmp_path: Path
) -> None:
    """--output-bag: the recording's own messages, a Detection3DArray a frame and a PoseStamped
    an object, reading back as --format ros prints them; the pose is the object's canonical
    frame in the camera's."""
    from rosbags.highlevel import AnyReader

    bag = write_recording(bag_path(tmp_path, kind), kind, [example_depth()] * 3,
                          parse_intrinsics(str(CAMERA)))  # fmt: skip
    out = tmp_path / out_name
    result = runner.invoke(app, ["scene", str(bag), *BUDGET, "--every", "2", "--format", "ros",
                                 "--output-bag", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    printed = lines(result.stdout)
    assert len(printed) == 2  # frames 0 and 2
    with AnyReader([out]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts[DEPTH_TOPIC] == 3 and counts["/itnet/detections"] == 2
        assert counts["/itnet/poses"] == sum(len(p["detections"]) for p in printed)
        wanted = [c for c in reader.connections if c.topic == "/itnet/detections"]
        messages = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(wanted)]
    for message, expected in zip(messages, printed):
        assert message.header.stamp.sec == expected["header"]["stamp"]["sec"]
        assert message.header.stamp.nanosec == expected["header"]["stamp"]["nanosec"]
        assert message.header.frame_id == FRAME_ID
        assert len(message.detections) == len(expected["detections"]) == 3
        for got, want in zip(message.detections, expected["detections"]):
            hypothesis = got.results[0]
            assert hypothesis.hypothesis.class_id == want["results"][0]["hypothesis"]["class_id"]
            assert hypothesis.hypothesis.score == pytest.approx(
                want["results"][0]["hypothesis"]["score"]
            )
            position = want["results"][0]["pose"]["pose"]["position"]
            assert hypothesis.pose.pose.position.x == pytest.approx(position["x"])
            assert got.bbox.size.y == pytest.approx(want["bbox"]["size"]["y"])


def test_the_ros_pose_is_the_inverse_of_the_scene_pose(tmp_path: Path, png_answer: dict) -> None:
    """--format ros: position and orientation are T_camera_from_canonical of the object."""
    result = runner.invoke(app, ["scene", str(EXAMPLES / "scene.png"), "--intrinsics", str(CAMERA),
                                 *BUDGET, "--format", "ros"])  # fmt: skip
    assert result.exit_code == 0, result.output
    detections = lines(result.stdout)[0]["detections"]
    for detection, obj in zip(detections, png_answer["objects"]):
        pose = detection["results"][0]["pose"]["pose"]
        q = pose["orientation"]
        camera_from_canonical = invert_rigid(np.asarray(obj["T_canonical_from_input"]))
        rotation = quat_wxyz_to_matrix(quat_xyzw_to_wxyz([q["x"], q["y"], q["z"], q["w"]]))
        np.testing.assert_allclose(rotation, camera_from_canonical[:3, :3], atol=2e-3)
        position = [pose["position"][k] for k in "xyz"]
        np.testing.assert_allclose(position, camera_from_canonical[:3, 3], atol=5e-3)
        assert detection["results"][0]["hypothesis"]["class_id"] == obj["category"]


def test_the_rerun_log_holds_every_frame_and_object(tmp_path: Path) -> None:
    """--rerun out.rrd: on the frame timeline, the points and one box per object in each frame."""
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    bag = write_recording(tmp_path / "rec.bag", "ros1", [example_depth()] * 2,
                          parse_intrinsics(str(CAMERA)))  # fmt: skip
    rrd = tmp_path / "out.rrd"
    result = runner.invoke(app, ["scene", str(bag), *BUDGET, "--rerun", str(rrd)])
    assert result.exit_code == 0, result.output
    rows: dict[str, int] = {}
    boxes = []
    for chunk in RrdReader(rrd).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
        if chunk.entity_path == "/camera/objects" and not chunk.is_static:
            assert "frame" in chunk.timeline_names
            batch = chunk.to_record_batch()
            column = next(n for n in batch.schema.names if "half_sizes" in n.lower())
            boxes.extend(len(v) for v in batch.column(column).to_pylist())
    assert rows["/camera/points"] == 2 and rows["/camera/objects"] == 2
    assert boxes == [3, 3]


def test_itnet_pose_takes_a_point_cloud_topic(tmp_path: Path) -> None:
    """An object's PointCloud2 messages posed as the same clouds from files are."""
    files = [EXAMPLES / "chair_a.ply", EXAMPLES / "chair_b.ply"]
    bag = write_clouds(tmp_path / "chairs", "sqlite3", [read_cloud(f) for f in files])
    from_bag = runner.invoke(app, ["pose", str(bag), "--json", "--max-iterations", "10"])
    from_files = runner.invoke(app, ["pose", *map(str, files), "--json", "--max-iterations", "10"])
    assert from_bag.exit_code == 0 and from_files.exit_code == 0, (
        from_bag.output + from_files.output
    )
    got, expected = lines(from_bag.stdout), lines(from_files.stdout)
    assert [r["frame"] for r in got] == [0, 1] and all(r["topic"] == CLOUD_TOPIC for r in got)
    for a, b in zip(got, expected):
        assert a["iterations"] == b["iterations"]
        np.testing.assert_allclose(
            a["T_canonical_from_input"], b["T_canonical_from_input"], atol=1e-4
        )
