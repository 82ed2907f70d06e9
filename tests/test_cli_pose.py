import json

import numpy as np
from typer.testing import CliRunner

from itnet.cli import app
from itnet.cloud_io import write_ply

runner = CliRunner()


def test_version():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.startswith("itnet ")


def test_pose_json_lines_and_bad_files_do_not_stop_the_others(tmp_path, tiny_model_dir, rng):
    cloud = rng.normal(size=(300, 3)) * [0.5, 0.3, 0.2] + [0.0, 0.0, 2.0]
    write_ply(tmp_path / "a.ply", cloud)
    np.save(tmp_path / "b.npy", cloud * 100)
    (tmp_path / "bad.ply").write_bytes(b"ply\ngarbage")
    args = [
        "pose",
        str(tmp_path / "a.ply"),
        str(tmp_path / "missing.pcd"),
        str(tmp_path / "bad.ply"),
        str(tmp_path / "b.npy"),
        "--model",
        "tiny",
        "--model-dir",
        str(tiny_model_dir),
        "--json",
        "--max-iterations",
        "3",
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert [line["file"] for line in lines] == [str(tmp_path / "a.ply"), str(tmp_path / "b.npy")]
    for line in lines:
        assert {
            "T_canonical_from_input",
            "quat_wxyz",
            "quat_xyzw",
            "translation",
            "iterations",
            "stopped_by",
        } <= set(line)
        assert line["iterations"] == 3 and line["stopped_by"] == "max_iterations"
        assert np.allclose(line["quat_xyzw"], np.roll(line["quat_wxyz"], -1))
    # same cloud in another unit: same rotation, translation scaled
    a, b = (np.array(line["T_canonical_from_input"]) for line in lines)
    assert np.allclose(a[:3, :3], b[:3, :3], atol=1e-4)
    assert np.allclose(a[:3, 3] * 100, b[:3, 3], rtol=1e-3, atol=1e-3)
    assert "missing.pcd: no such file" in result.stderr
    assert "bad.ply" in result.stderr


def test_pose_unknown_model_is_a_clear_error(tmp_path, tiny_model_dir, rng):
    write_ply(tmp_path / "a.ply", rng.normal(size=(100, 3)))
    result = runner.invoke(
        app,
        ["pose", str(tmp_path / "a.ply"), "--model", "sofa", "--model-dir", str(tiny_model_dir)],
    )
    assert (
        result.exit_code == 2
        and "unknown model 'sofa'" in result.stderr
        and "tiny" in result.stderr
    )


def test_pose_says_when_the_shipped_chairs_centre_was_corrected():
    """The shipped chair's card has both centre corrections: the line says so, --no-centre
    turns it off, and --viewpoint (the example is in its camera's frame) picks the second."""
    from pathlib import Path

    example = str(Path(__file__).resolve().parents[1] / "itnet/examples/chair_a.ply")
    on = runner.invoke(app, ["pose", example, "--model", "chair"])
    off = runner.invoke(app, ["pose", example, "--model", "chair", "--no-centre"])
    assert on.exit_code == off.exit_code == 0, on.output + off.output
    assert "centre-corrected" in on.stdout and "centre-corrected" not in off.stdout
    seen = runner.invoke(
        app, ["pose", example, "--model", "chair", "--viewpoint", "0,0,0", "--json"]
    )
    assert seen.exit_code == 0, seen.output
    line = json.loads(seen.stdout)
    assert line["centre"] is True and line["centre_viewpoint"] is True
    bad = runner.invoke(app, ["pose", example, "--model", "chair", "--viewpoint", "0,0"])
    assert bad.exit_code == 2 and "expected three numbers" in bad.output


def test_pose_holds_the_shipped_chair_upright_with_up():
    """--up: the line says 'held upright' and the pose takes that direction onto +y; a bad one
    is a usage error (three numbers) or the file's error (the zero vector)."""
    from pathlib import Path

    example = str(Path(__file__).resolve().parents[1] / "itnet/examples/chair_a.ply")
    up = [0.1, -1.0, 0.2]
    held = runner.invoke(app, ["pose", example, "--model", "chair", "--up", "0.1,-1,0.2"])
    assert held.exit_code == 0 and "held upright" in held.stdout, held.output
    line = runner.invoke(app, ["pose", example, "--model", "chair", "--up", "0.1,-1,0.2", "--json"])
    result = json.loads(line.stdout)
    rotation = np.asarray(result["T_canonical_from_input"])[:3, :3]
    np.testing.assert_allclose(rotation @ (np.array(up) / np.linalg.norm(up)), [0, 1, 0], atol=1e-4)
    bad = runner.invoke(app, ["pose", example, "--model", "chair", "--up", "0,1"])
    assert bad.exit_code == 2 and "expected three numbers" in bad.output
    zero = runner.invoke(app, ["pose", example, "--model", "chair", "--up", "0,0,0"])
    assert zero.exit_code == 2 and "zero" in zero.output
