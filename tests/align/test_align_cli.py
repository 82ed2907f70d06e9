"""``itnet-align`` / ``itnet align`` end to end, in-process, with the tiny random model."""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from itnet.alignment.hypotheses import relative_pose
from itnet.alignment.overlap import overlap_score
from itnet.cli import align_app, app
from itnet.cloud_io import read_cloud, write_ply
from itnet.geometry import apply_rigid
from itnet.preprocess import estimate_normalization

EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"
A, B = EXAMPLES / "chair_a.ply", EXAMPLES / "chair_b.ply"
runner = CliRunner()


def _reply(output: str) -> dict:
    """The JSON reply among a command's output lines (a warning on stderr may follow it)."""
    return json.loads(next(line for line in reversed(output.splitlines()) if line.startswith("{")))


def run(tiny_model_dir, *args, main=False):
    argv = [*(["align"] if main else []), *map(str, args), "--model", "tiny",
            "--model-dir", str(tiny_model_dir)]  # fmt: skip
    return runner.invoke(app if main else align_app, argv)


def test_json_reply(tiny_model_dir):
    result = run(
        tiny_model_dir,
        A,
        B,
        "--json",
        "--symmetry",
        "none",
        "--starts",
        "1",
        "--no-refine",
        "--no-rivals",
    )
    assert result.exit_code == 0, result.output
    reply = json.loads(result.stdout)
    t = np.array(reply["T_b_from_a"])
    assert t.shape == (4, 4) and np.allclose(t[3], [0, 0, 0, 1])
    assert np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-5)  # float32 network poses
    # each cloud: its served pose (5 steps, the tiny model's) and 4 fused runs as alternatives
    assert reply["iterations"] == 20
    assert reply["elapsed_ms"] > 0 and 0 < reply["probability"] < 1
    # No refinement, no rivals: the answer is exactly the composed poses, inv(T_cb) . T_ca.
    assert reply["hypothesis"] == "itnet" and reply["refined"] is False
    t_ca = reply["T_canonical_from_a"]["T_canonical_from_input"]
    t_cb = reply["T_canonical_from_b"]["T_canonical_from_input"]
    assert np.allclose(t, relative_pose(t_ca, t_cb), atol=1e-12)
    assert reply["T_canonical_from_a"]["stopped_by"] == "max_iterations"


def test_text_output_and_the_subcommand_agree(tiny_model_dir):
    # a budget no loaded test machine cuts short: both must take every step to agree
    alias = run(tiny_model_dir, A, B, "--budget-ms", "2000")
    sub = run(tiny_model_dir, A, B, "--budget-ms", "2000", main=True)
    assert alias.exit_code == sub.exit_code == 0, alias.output + sub.output
    assert alias.stdout.startswith("T_b_from_a (moves A onto B):")
    matrix = [line for line in alias.stdout.splitlines()[1:5]]
    assert matrix == sub.stdout.splitlines()[1:5]
    # Each cloud's served pose: 4 fused runs of the tiny model's 5 iterations.
    assert "rotation" in alias.stdout and "10 iterations" in alias.stdout
    assert "likely right" in alias.stdout


def test_output_writes_a_moved_onto_b(tiny_model_dir, tmp_path):
    out = tmp_path / "aligned.ply"
    result = run(tiny_model_dir, A, B, "--json", "--output", out)
    assert result.exit_code == 0, result.output
    reply = json.loads(result.stdout)
    moved = read_cloud(out)
    expected = apply_rigid(np.array(reply["T_b_from_a"]), read_cloud(A))
    assert moved.shape == expected.shape
    assert np.allclose(moved, expected, atol=1e-5)
    assert reply["output"] == str(out)


def test_icp_is_the_default_when_open3d_is_installed(tiny_model_dir):
    pytest.importorskip("open3d")
    default = json.loads(run(tiny_model_dir, A, B, "--json").stdout)
    skipped = json.loads(run(tiny_model_dir, A, B, "--json", "--no-refine").stdout)
    assert default["icp_distance"] > 0 and default["hypotheses"][1]["source"] == "itnet+icp"
    assert skipped["refined"] is False and skipped["icp_distance"] == 0
    assert not any("+icp" in h["source"] for h in skipped["hypotheses"])
    assert "--no-refine" in runner.invoke(align_app, ["--help"]).stdout


def test_refine_reports_fit(tiny_model_dir):
    result = run(tiny_model_dir, A, B, "--json", "--refine")
    assert result.exit_code == 0, result.output
    reply = json.loads(result.stdout)
    sources = [h["source"] for h in reply["hypotheses"]]
    # the composed pose as served and refined first; where it is in doubt, the rivals among
    # (the served pose and its 4 runs) for each cloud, crossed, times 4 quarter turns
    assert sources[:2] == ["itnet", "itnet+icp"] and len(sources) <= 2 + 6
    assert reply["considered"] in (0, 5 * 5 * 4) and (len(sources) > 2) == (reply["considered"] > 0)
    assert all(s.startswith("itnet") and s.endswith("+icp") for s in sources[1:])
    assert 0 <= reply["fitness"] <= 1 and reply["timings_ms"]["composed"] > 0
    assert reply["icp_distance"] == pytest.approx(2 * reply["inlier_distance"], rel=1e-3)
    refined = reply["hypotheses"][1:]
    assert all(0 <= h["icp"]["fitness"] <= 1 and h["icp"]["rmse"] >= 0 for h in refined)
    assert all(0 <= h["probability"] <= 1 for h in reply["hypotheses"])
    best = max(reply["hypotheses"], key=lambda h: h["probability"])
    assert reply["hypothesis"] == best["source"]  # the likeliest is the answer


@pytest.mark.parametrize("which", ["a", "b"])
def test_missing_file_exits_2_with_its_name(tiny_model_dir, tmp_path, which):
    missing = tmp_path / "nope.ply"
    args = (missing, B) if which == "a" else (A, missing)
    result = run(tiny_model_dir, *args)
    assert result.exit_code == 2
    assert "error:" in result.stderr and str(missing) in result.stderr
    assert "no such file" in result.stderr
    assert result.stdout == ""


def test_unreadable_and_unusable_clouds_exit_2(tiny_model_dir, tmp_path):
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"this is not a point cloud")
    result = run(tiny_model_dir, A, garbage)
    assert result.exit_code == 2 and str(garbage) in result.stderr
    tiny_cloud = tmp_path / "five.ply"
    write_ply(tiny_cloud, np.random.default_rng(0).normal(size=(5, 3)))
    result = run(tiny_model_dir, tiny_cloud, B)
    assert result.exit_code == 2
    assert str(tiny_cloud) in result.stderr and "too few" in result.stderr


def test_bad_options_exit_2(tiny_model_dir, tmp_path):
    assert run(tiny_model_dir, A, B, "--output", tmp_path / "x.pcd").exit_code == 2
    result = run(tiny_model_dir, A, B, "--symmetry", "mirror")
    assert result.exit_code == 2 and "--symmetry" in result.stderr


def test_shipped_examples_are_small_scans_of_one_chair():
    truth = json.loads((EXAMPLES / "chair_truth.json").read_text())
    a, b = read_cloud(A), read_cloud(B)
    assert A.stat().st_size < 20_000 and B.stat().st_size < 20_000
    assert [len(a), len(b)] == truth["points"]
    # The true T_b_from_a puts A on B where the two views overlap.
    scale = estimate_normalization(b).scale
    fitness, rmse = overlap_score(a, b, np.array(truth["T_b_from_a"]), 0.1 * scale)
    wrong, _ = overlap_score(a, b, np.eye(4), 0.1 * scale)
    assert fitness > 0.3 > wrong
    assert rmse < 0.05 * scale


def test_summary_names_the_runner_up_and_says_when_rivals_were_judged(capsys):
    from itnet.alignment.hypotheses import Hypothesis
    from itnet.alignment.pipeline import Alignment, PoseEstimate
    from itnet.commands.align import _print_summary
    from itnet.geometry import axis_angle_to_matrix, rigid_from_rotation_translation

    def hyp(deg, probability, source):
        pose = rigid_from_rotation_translation(axis_angle_to_matrix([0, 1, 0], np.radians(deg)), 0)
        return Hypothesis(pose, source, 0.5, 0.01, probability=probability)

    run = PoseEstimate(np.eye(4), 6, 1.0, "max_iterations")
    times = {"total": 1.0, "itnet": 0.5, "composed": 0.2, "rivals": 0.3}

    def summary(hyps, considered):
        _print_summary(Alignment(hyps[1].T_b_from_a, run, run, hyps, 1, times, 48,
                                 considered).to_dict())  # fmt: skip
        return capsys.readouterr().out

    rivals = [hyp(0, 0.3, "itnet+icp"), hyp(90, 0.8, "itnet a1 b0+yaw90+icp")]
    text = summary(rivals, 64)
    assert "hypothesis itnet a1 b0+yaw90+icp, 80% likely right" in text
    assert "runner-up itnet+icp 30%" in text and "1 distinct rivals of 64" in text
    same = summary([hyp(0, 0.9, "itnet"), hyp(2, 0.95, "itnet+icp")], 0)
    assert "runner-up" not in same and "in doubt" not in same  # the same answer, refined


@pytest.mark.parametrize("name", ["chair", "chair_quarter"])
def test_the_shipped_model_aligns_the_shipped_examples(name):
    """The README's command, with the shipped chair model (and a budget a loaded test machine
    does not cut short): within 5 degrees of the truth. The quarter-turn example needs the
    rivals: one plain run, composed alone, is a quarter turn off."""
    from itnet.geometry import rotation_error_deg

    pytest.importorskip("open3d")
    files = [str(EXAMPLES / f"{name}_a.ply"), str(EXAMPLES / f"{name}_b.ply")]
    truth = np.array(json.loads((EXAMPLES / f"{name}_truth.json").read_text())["T_b_from_a"])

    def error(*options):
        result = runner.invoke(align_app, [*files, "--refine", "--json", "--budget-ms", "1000",
                                           *options])  # fmt: skip
        assert result.exit_code == 0, result.output
        t = np.array(json.loads(result.stdout)["T_b_from_a"])
        return float(rotation_error_deg(t[:3, :3], truth[:3, :3]))

    assert error() < 5.0
    if name == "chair_quarter":
        assert error("--starts", "1", "--symmetry", "none", "--no-rivals") > 45.0


def test_the_shipped_table_poses_and_aligns_its_example_within_its_symmetry():
    """The installed table model (yaw180) on a held-out ModelNet10 table scanned twice in metres:
    the pose is right up to the table's half turn, and the pair is aligned (no --model-dir: the
    models that ship)."""
    from itnet.symmetry import symmetric_rotation_error_deg

    truth = json.loads((EXAMPLES / "table_truth.json").read_text())
    a = EXAMPLES / "table_a.ply"
    pose = CliRunner().invoke(app, ["pose", str(a), "--model", "table", "--json"])
    assert pose.exit_code == 0, pose.output
    got = np.array(_reply(pose.output)["T_canonical_from_input"])
    want = np.array(truth["T_canonical_from_a"])
    assert symmetric_rotation_error_deg(got[:3, :3], want[:3, :3], "yaw180") < 10
    centre_error = np.linalg.norm(got[:3, :3].T @ got[:3, 3] - want[:3, :3].T @ want[:3, 3])
    assert centre_error < 0.1 * truth["radius_m"]

    assert_aligns_example_pair("table")


def test_the_shipped_toilet_aligns_its_example_pair():
    """The installed toilet model on a held-out ModelNet10 toilet scanned twice in metres (the
    first pair made, not picked). The composed served poses miss; the pair is aligned all the
    same, because itnet-align weighs each view's runs (and 4 fused runs where the toilet's card
    plans one) and lets ICP and the overlap score choose."""
    assert_aligns_example_pair("toilet")


def test_the_shipped_bed_aligns_its_example_pair_and_auto_finds_the_bed_given_up():
    """The installed bed model (itnet-align fuses 4 runs a cloud and weighs each of them) on a
    held-out ModelNet10 bed scanned twice in metres (the first pair made, seed 3). With --model
    auto and each scan's up (a level-sensing camera's: the truth's canonical +y in the scan's
    frame) the upright classifier joins and the pair is a bed. Without up this pair is unsure
    (bed 0.54): a low, long shape seen edge-on, the bed's commonest confusions."""
    assert_aligns_example_pair("bed")
    a, b = EXAMPLES / "bed_a.ply", EXAMPLES / "bed_b.ply"
    truth = json.loads((EXAMPLES / "bed_truth.json").read_text())
    ups = [
        ",".join(f"{v:.6f}" for v in np.array(truth[k])[:3, :3].T @ [0.0, 1.0, 0.0])
        for k in ("T_canonical_from_a", "T_canonical_from_b")
    ]
    args = [str(a), str(b), "--model", "auto", "--json", "--up-a", ups[0], "--up-b", ups[1]]
    auto = CliRunner().invoke(align_app, args)
    assert auto.exit_code == 0, auto.output
    assert _reply(auto.output)["model"] == "bed"


def test_the_shipped_night_stand_aligns_its_pair_with_each_scans_up_and_not_without():
    """The night stand's model requires up (its card): itnet-align says so and how to give it;
    with each scan's up direction (a level-sensing camera's, in the truth file) the pair of a
    held-out night stand (the first pair made, seed 3) is aligned, both poses upright."""
    truth = json.loads((EXAMPLES / "night_stand_truth.json").read_text())
    a, b = EXAMPLES / "night_stand_a.ply", EXAMPLES / "night_stand_b.ply"
    refused = CliRunner().invoke(align_app, [str(a), str(b), "--model", "night_stand"])
    assert refused.exit_code == 2 and "--up-a and --up-b" in refused.output
    xyz = lambda v: ",".join(map(str, v))  # noqa: E731
    reply = assert_aligns_example_pair(
        "night_stand", "--up-a", xyz(truth["up_a"]), "--up-b", xyz(truth["up_b"])
    )
    for cloud in "ab":
        pose = np.array(reply[f"T_canonical_from_{cloud}"]["T_canonical_from_input"])
        up = np.array(truth[f"up_{cloud}"])
        assert np.allclose(pose[:3, :3] @ up, [0, 1, 0], atol=1e-4)
        assert np.allclose(reply[f"up_{cloud}"], up)


def test_up_holds_both_clouds_poses_upright_and_a_zero_up_is_refused(tiny_model_dir):
    up = [0.2, -1.0, 0.1]
    result = run(tiny_model_dir, A, B, "--json", "--no-refine", "--up", "0.2,-1,0.1")
    assert result.exit_code == 0, result.output
    reply = json.loads(result.stdout)
    unit = np.array(up) / np.linalg.norm(up)
    for cloud in "ab":
        pose = np.array(reply[f"T_canonical_from_{cloud}"]["T_canonical_from_input"])
        assert np.allclose(pose[:3, :3] @ unit, [0, 1, 0], atol=1e-4)
        assert reply[f"up_{cloud}"] == up
    # every hypothesis keeps A's up on B's: the poses are upright, the symmetries turn about up
    for h in reply["hypotheses"]:
        t = np.array(h["T_b_from_a"])
        assert np.allclose(t[:3, :3] @ unit, unit, atol=1e-3)
    zero = run(tiny_model_dir, A, B, "--no-refine", "--up-b", "0,0,0")
    assert zero.exit_code == 2 and "zero vector" in zero.output
    bad = run(tiny_model_dir, A, B, "--up", "1,2")
    assert bad.exit_code == 2 and "three numbers" in bad.output


def assert_aligns_example_pair(model: str, *extra: str) -> dict:
    """``itnet-align MODEL_a.ply MODEL_b.ply --model MODEL`` (the installed model) moves A within
    10° of the truth, its centroid within 0.1 of the object's radius; -> the JSON reply."""
    from itnet.geometry import rotation_error_deg

    truth = json.loads((EXAMPLES / f"{model}_truth.json").read_text())
    a, b = EXAMPLES / f"{model}_a.ply", EXAMPLES / f"{model}_b.ply"
    # a budget no loaded test machine cuts short: the answer, not the time, is under test here
    args = [str(a), str(b), "--model", model, "--json", "--budget-ms", "1000", *extra]
    aligned = CliRunner().invoke(align_app, args)
    assert aligned.exit_code == 0, aligned.output
    moved = np.array(_reply(aligned.output)["T_b_from_a"])
    true_b_from_a = np.array(truth["T_b_from_a"])
    assert rotation_error_deg(moved[:3, :3], true_b_from_a[:3, :3]) < 10
    centroid = read_cloud(a).mean(axis=0)
    shift = apply_rigid(moved, centroid[None]) - apply_rigid(true_b_from_a, centroid[None])
    assert np.linalg.norm(shift) < 0.1 * truth["radius_m"]
    return _reply(aligned.output)
