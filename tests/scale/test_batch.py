"""``itnet batch pose|align|scene`` on a local Ray (2 CPUs): the rows of ``itnet pose --json`` /
``itnet align --json`` / ``itnet scene --json``, bad files as error rows, inputs as files, folders
and globs, resuming."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.cli import app

pytestmark = [pytest.mark.ray, pytest.mark.slow]
EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"
runner = CliRunner()


@pytest.fixture(scope="module")
def clouds(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """12 turned copies of the example scans in a folder, and a file that is not a cloud."""
    from itnet.scale.bench_batch import make_clouds

    folder = tmp_path_factory.mktemp("clouds")
    make_clouds(folder, 12, seed=3)
    (folder / "broken.ply").write_text("ply\nformat nonsense\n")
    return folder


def itnet_pose_rows(files: list[Path]) -> dict[str, dict]:
    """What ``itnet pose --json`` prints for the files, by file."""
    result = runner.invoke(app, ["pose", "--json", *map(str, files)])
    rows = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    return {row["file"]: row for row in rows}


def read_rows(path: Path) -> list[dict]:
    if path.suffix == ".jsonl":
        return [json.loads(line) for line in path.read_text().splitlines()]
    import pyarrow.parquet as pq

    rows = pq.read_table(path).to_pylist()
    return [{k: v for k, v in row.items() if v is not None} for row in rows]


def test_batch_pose_gives_itnet_poses_answers(local_ray: None, clouds: Path, tmp_path: Path):
    """Folder + glob + a file named twice: every cloud once, the same pose, iterations and stop
    reason as ``itnet pose --json``, and the broken file as a row with an error."""
    out = tmp_path / "poses.parquet"
    inputs = [str(clouds), str(clouds / "cloud_0000*.ply"), str(clouds / "cloud_00001.ply")]
    result = runner.invoke(app, ["batch", "pose", *inputs, "-o", str(out), "--workers", "2"])
    assert result.exit_code == 0, result.output
    rows = read_rows(out)
    files = sorted(clouds.glob("*.ply"))
    assert sorted(row["file"] for row in rows) == sorted(map(str, files))
    expected = itnet_pose_rows(files)
    for row in rows:
        if row["file"].endswith("broken.ply"):
            assert "error" in row and "T_canonical_from_input" not in row
            continue
        want = expected[row["file"]]
        assert set(want) <= set(row)
        assert (row["iterations"], row["stopped_by"], row["model"]) == (
            want["iterations"], want["stopped_by"], want["model"],
        )  # fmt: skip
        np.testing.assert_allclose(
            row["T_canonical_from_input"], want["T_canonical_from_input"], atol=1e-6
        )
        np.testing.assert_allclose(row["quat_wxyz"], want["quat_wxyz"], atol=1e-6)
    assert not out.with_name(out.name + ".parts").exists()


def test_batch_pose_resumes(local_ray: None, clouds: Path, tmp_path: Path) -> None:
    """A stopped job's parts and an earlier output are skipped; the merged table has every cloud
    once. (A part written by hand stands for the stopped job: its rows are kept as they are.)"""
    from itnet.scale.table import BatchTable

    out = tmp_path / "poses.jsonl"
    files = sorted(map(str, clouds.glob("cloud_*.ply")))
    first = runner.invoke(app, ["batch", "pose", *files[:4], "-o", str(out), "--no-progress"])
    assert first.exit_code == 0, first.output
    assert len(read_rows(out)) == 4
    marker = {"file": files[4], "model": "chair", "iterations": -1}
    BatchTable(out, ("file",)).write_part([marker])
    again = runner.invoke(app, ["batch", "pose", *files, "-o", str(out), "--workers", "2"])
    assert again.exit_code == 0, again.output
    assert f"({len(files) - 5} new, 5 already there, 0 errors)" in again.output
    rows = read_rows(out)
    assert sorted(row["file"] for row in rows) == files
    assert [row for row in rows if row["file"] == files[4]] == [marker]


def test_batch_scene_gives_itnet_scenes_answers(local_ray: None, tmp_path: Path) -> None:
    """A folder of depth frames, a scene cloud and a recording: a row a file (a recording, a row
    a frame, with its header) with the objects ``itnet scene --json`` finds there (named alike,
    each posed), a broken image as a row with the CLI's error, and a second run that finds
    everything done."""
    from benchmarks.recording import write_recording
    from itnet.scene import parse_intrinsics
    from itnet.scene.depth_io import png_to_depth
    from itnet.scene.inputs import from_png

    camera = str(EXAMPLES / "scene_camera.json")
    frames = tmp_path / "frames"
    (frames / "later").mkdir(parents=True)
    png = (EXAMPLES / "scene.png").read_bytes()
    (frames / "frame_0.png").write_bytes(png)
    (frames / "later" / "frame_1.png").write_bytes(png)
    cloud = from_png(png, parse_intrinsics(camera)).points.astype(np.float32)
    np.save(frames / "room.npy", cloud)  # (N, 3): a scene cloud, camera frame
    (frames / "broken.png").write_bytes(b"not a png")
    (frames / "notes.md").write_text("not a scene")  # no scene suffix in a folder: not taken
    bag = write_recording(frames / "rec", "mcap", [png_to_depth(png)] * 2, parse_intrinsics(camera))
    out = tmp_path / "scenes.parquet"
    run = ["batch", "scene", str(frames), "--intrinsics", camera, "--budget-ms", "2000",
           "-o", str(out), "--no-progress"]  # fmt: skip
    result = runner.invoke(app, run)
    assert result.exit_code == 0, result.output
    rows = {(row["file"], row.get("frame")): row for row in read_rows(out)}
    files = sorted(str(p) for p in frames.rglob("*") if p.suffix in (".png", ".npy"))
    assert sorted(rows) == sorted([(f, None) for f in files] + [(str(bag), 0), (str(bag), 1)])
    cli = runner.invoke(app, ["scene", *files, str(bag), "--intrinsics", camera, "--budget-ms",
                              "2000", "--json", "--no-indices"])  # fmt: skip
    assert cli.exit_code == 2  # the broken image
    expected = {
        (r["file"], r.get("frame")): r for r in map(json.loads, cli.stdout.splitlines()) if r
    }
    for key, row in rows.items():
        if key[0].endswith("broken.png"):
            assert "objects" not in row and row["error"] in cli.output
            continue
        names = [o["category"] for o in row["objects"]]
        assert names == [o["category"] for o in expected[key]["objects"]]
        assert sorted(names) == ["chair", "night_stand", "toilet"]
        assert all(o["T_canonical_from_input"] is not None for o in row["objects"])
        assert all("indices" not in o or o["indices"] is None for o in row["objects"])
        if key[0] == str(bag):
            assert (
                row["header"] == expected[key]["header"] and row["topic"] == expected[key]["topic"]
            )
    again = runner.invoke(app, run)
    assert again.exit_code == 0 and "(0 new, 5 already there, 0 errors)" in again.output


def test_batch_align_gives_itnet_aligns_answers(local_ray: None, tmp_path: Path) -> None:
    """A CSV manifest of the shipped pair, the pair reversed, and a pair with a missing file:
    the same T_b_from_a as ``itnet align --json``, the missing file as an error row."""
    shutil.copy(EXAMPLES / "chair_a.ply", tmp_path / "a.ply")
    shutil.copy(EXAMPLES / "chair_b.ply", tmp_path / "b.ply")
    (tmp_path / "pairs.csv").write_text("a,b\na.ply,b.ply\nb.ply,a.ply\na.ply,gone.ply\n")
    out = tmp_path / "pairs.parquet"
    args = ["--no-refine", "--max-iterations", "6", "--budget-ms", "5000"]  # no stage skipped
    result = runner.invoke(
        app, ["batch", "align", str(tmp_path / "pairs.csv"), "-o", str(out), *args]
    )
    assert result.exit_code == 0, result.output
    rows = {(Path(r["cloud_a"]).name, Path(r["cloud_b"]).name): r for r in read_rows(out)}
    assert "gone.ply" in rows[("a.ply", "gone.ply")]["error"]
    for a, b in [("a.ply", "b.ply"), ("b.ply", "a.ply")]:
        single = runner.invoke(
            app, ["align", str(tmp_path / a), str(tmp_path / b), "--json", *args]
        )
        want = json.loads(single.stdout.splitlines()[-1])
        got = rows[(a, b)]
        assert (got["hypothesis"], got["iterations"]) == (want["hypothesis"], want["iterations"])
        np.testing.assert_allclose(got["T_b_from_a"], want["T_b_from_a"], atol=1e-6)


def test_batch_align_takes_each_pairs_up_from_the_manifest(local_ray: None, tmp_path: Path) -> None:
    """JSON Lines with up_a, up_b (a list, or 'x,y,z'): the night stand, whose model requires
    up, aligns its example pair as ``itnet align --up-a --up-b`` does; a pair without ups is an
    error row that says the model needs them."""
    truth = json.loads((EXAMPLES / "night_stand_truth.json").read_text())
    a, b = EXAMPLES / "night_stand_a.ply", EXAMPLES / "night_stand_b.ply"
    xyz = lambda v: ",".join(map(str, v))  # noqa: E731
    lines = [{"a": str(a), "b": str(b), "up_a": truth["up_a"], "up_b": xyz(truth["up_b"])},
             {"a": str(b), "b": str(a)}]  # fmt: skip
    (tmp_path / "pairs.jsonl").write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    out = tmp_path / "pairs.jsonl.out.jsonl"
    args = ["--model", "night_stand", "--no-refine", "--budget-ms", "5000"]
    result = runner.invoke(
        app, ["batch", "align", str(tmp_path / "pairs.jsonl"), "-o", str(out), *args]
    )
    assert result.exit_code == 0, result.output
    rows = {(Path(r["cloud_a"]).name, Path(r["cloud_b"]).name): r for r in read_rows(out)}
    assert "needs 'up'" in rows[(b.name, a.name)]["error"]
    got = rows[(a.name, b.name)]
    assert np.allclose(got["up_a"], truth["up_a"]) and np.allclose(got["up_b"], truth["up_b"])
    ups = ["--up-a", xyz(truth["up_a"]), "--up-b", xyz(truth["up_b"])]
    single = runner.invoke(app, ["align", str(a), str(b), "--json", *args, *ups])
    want = json.loads(single.stdout.splitlines()[-1])
    np.testing.assert_allclose(got["T_b_from_a"], want["T_b_from_a"], atol=1e-6)


def test_a_manifests_bad_up_is_refused_with_its_row(tmp_path: Path) -> None:
    from itnet.scale.inputs import InputError, read_manifest

    (tmp_path / "ok.csv").write_text('a,b,up_a\nx.ply,y.ply,"0,-1,0"\nx.ply,z.ply,\n')
    assert read_manifest(tmp_path / "ok.csv") == [
        (str(tmp_path / "x.ply"), str(tmp_path / "y.ply"), "0.0,-1.0,0.0", ""),
        (str(tmp_path / "x.ply"), str(tmp_path / "z.ply"), "", ""),
    ]
    for bad, says in (
        ('"0,0,0"', "zero vector"),
        ('"1,2"', "three finite"),
        ("up", "three finite"),
    ):
        (tmp_path / "bad.csv").write_text(f"a,b,up_b\nx.ply,y.ply,{bad}\n")
        with pytest.raises(InputError, match=f"row 1: .*{says}"):
            read_manifest(tmp_path / "bad.csv")


def test_batch_refuses_what_it_cannot_do(tmp_path: Path) -> None:
    """Errors the driver finds before Ray starts: exit 2 and a message."""
    cloud = str(EXAMPLES / "chair_a.ply")
    cases = [
        (["batch", "pose", str(tmp_path / "nothing*.ply"), "-o", str(tmp_path / "p.parquet")],
         "no cloud files"),
        (["batch", "pose", cloud, "-o", str(tmp_path / "p.csv")], "must end in"),
        (["batch", "pose", cloud, "-o", str(tmp_path / "p.jsonl"), "--model", "no-such-model"],
         "unknown model"),
        (["batch", "align", str(tmp_path / "none.csv"), "-o", str(tmp_path / "p.jsonl")],
         "no such manifest"),
        (["batch", "scene", str(tmp_path), "-o", str(tmp_path / "s.jsonl")],
         "no depth images, clouds or recordings"),
        (["batch", "scene", cloud, "-o", str(tmp_path / "s.jsonl"), "--model-dir", str(tmp_path)],
         "no .onnx models found"),
        (["batch", "scene", cloud, "-o", str(tmp_path / "s.jsonl"), "--budget-ms", "0"],
         "--budget-ms: Input should be greater than 0"),
    ]  # fmt: skip
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output, (args, result.output)
