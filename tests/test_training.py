"""Tiny end-to-end training runs on synthetic shapes (seconds, not minutes)."""

import json
from pathlib import Path

import numpy as np
import pytest

from itnet.model.data import split_files
from itnet.model.shapes import Shape, check_yaw, yaw_rotation


def _chair_like(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """A seat (box) and a back (box on +z, rising along +y): clearly not symmetric about up."""
    seat = rng.uniform([-0.5, -0.05, -0.5], [0.5, 0.05, 0.5], size=(n // 2, 3))
    back = rng.uniform([-0.5, 0.05, 0.4], [0.5, 0.9, 0.5], size=(n - n // 2, 3))
    return np.concatenate([seat, back]) * rng.uniform(0.8, 1.2, size=3)


@pytest.fixture(scope="module")
def shape_folder(tmp_path_factory):
    rng = np.random.default_rng(0)
    root = tmp_path_factory.mktemp("shapes")
    for split, count in (("train", 12), ("test", 3)):
        (root / split).mkdir()
        for i in range(count):
            np.save(root / split / f"s{i:02d}.npy", _chair_like(rng))
    return root


def test_check_yaw_turns_back_a_rotated_shape():
    rng = np.random.default_rng(1)
    shapes = [Shape(f"s{i}", _chair_like(rng)) for i in range(12)]
    shapes[3] = Shape("s3", shapes[3].points @ yaw_rotation(1).T)
    kept, counts = check_yaw(shapes, references=8, sample=128)
    assert counts["turned"] == 1 and "turned" in kept[3].notes[0]
    assert np.allclose(kept[3].points, shapes[3].points @ yaw_rotation(3).T)


def test_split_keeps_test_apart_and_validation_from_train(shape_folder):
    files = split_files(shape_folder, "none", 0.2, seed=0)
    assert len(files["test"]) == 3 and len(files["val"]) >= 1
    assert not set(files["val"]) & set(files["train"])
    assert all("test" in str(f) for f in files["test"])


@pytest.mark.train
def test_train_resume_eval_export_pose(shape_folder, tmp_path):
    """itnet train (resume) -> eval (torch and onnx agree) -> export -> pose, on tiny data."""
    from typer.testing import CliRunner

    from itnet.cli import app

    runner = CliRunner()
    common = [
        "--data",
        str(shape_folder),
        "--category",
        "x",
        "--frame",
        "canonical",
        "--cache",
        str(tmp_path / "cache"),
    ]
    run = tmp_path / "run"
    train = [
        "train",
        *common,
        "--out",
        str(run),
        "--batch",
        "8",
        "--points",
        "64",
        "--iterations",
        "2",
        "--eval-every",
        "10",
        "--no-compile",  # compiled training: test_compiled_training_matches_eager
    ]
    assert runner.invoke(app, [*train, "--steps", "10"]).exit_code == 0
    result = runner.invoke(app, [*train, "--steps", "20"])  # resumes at step 10
    assert result.exit_code == 0, result.output
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [e["step"] for e in log if e.get("event") == "start"] == [0, 10]
    assert [e["step"] for e in log if e.get("event") == "val"] == [10, 20]
    # The moving average (on by default) competes with the raw weights at each validation.
    for entry in (e for e in log if e.get("event") == "val"):
        picked = entry[f"{entry['weights']}_val_accuracy"]
        assert (
            entry["val_accuracy"]
            == picked
            == max(entry["raw_val_accuracy"], entry["ema_val_accuracy"])
        )
        # precision beside accuracy: the chosen weights' median errors at the last iteration
        chosen = entry[f"{entry['weights']}_val_median_rotation_deg"]
        assert 0 <= entry["val_median_rotation_deg"] == chosen <= 180
        assert entry["val_median_translation"] >= 0
    assert (run / "best.pt").exists() and json.loads((run / "config.json").read_text())[
        "steps"
    ] == 20

    # Fine-tune from it on all three kinds of views, selecting on surface views; a bad scanner
    # name is refused.
    out_at = train.index("--out") + 1
    tune = [*train[:out_at], str(tmp_path / "tune"), *train[out_at + 1 :], "--steps", "10"]
    init = ["--init-from", str(run / "best.pt")]
    tuned = runner.invoke(
        app, [*tune, *init, "--val-scanner", "surface", "--surface-views", "--val-views", "3"]
    )
    assert tuned.exit_code == 0, tuned.output
    config = json.loads((tmp_path / "tune" / "config.json").read_text())
    # --val-views: 3 views of each held-out shape instead of 4
    starts = [
        json.loads(line)["val_scans"]
        for folder in (run, tmp_path / "tune")
        for line in (folder / "log.jsonl").read_text().splitlines()
        if '"start"' in line
    ]
    assert config["val_views"] == 3
    assert {k: v // 4 * 3 for k, v in starts[0].items()} == starts[-1], starts
    assert config["init_from"] == str(run / "best.pt")
    assert config["val_scan"] == {"splat": 1.0, "tolerance": 0.03}
    assert config["scan_mix"][1]["tolerance"] == 0.0 and config["scan_mix"][2]["splat"] == 1.0
    assert runner.invoke(app, [*tune, "--val-scanner", "nearest"]).exit_code == 2

    ev = ["eval", *common, "--views", "2", "--iterations", "3", "--points", "512"]
    ev += ["--scanner", "surface"]  # the torch and ONNX evaluations below on surface views
    bad = runner.invoke(app, [*ev[:-1], "nearest", "--checkpoint", str(run / "best.pt")])
    assert bad.exit_code == 2 and "unknown view rule" in bad.output
    torch_eval = runner.invoke(
        app, [*ev, "--checkpoint", str(run / "best.pt"), "--out", str(tmp_path / "e1")]
    )
    assert torch_eval.exit_code == 0, torch_eval.output
    onnx_path = tmp_path / "models" / "x.onnx"
    exported = runner.invoke(
        app,
        [
            "export",
            str(run / "best.pt"),
            "--out",
            str(onnx_path),
            "--name",
            "x",
            "--points",
            "512",
            "--report",
            str(tmp_path / "e1" / "report.json"),
        ],
    )
    assert exported.exit_code == 0, exported.output
    diff = float(exported.output.split("max |diff|")[1].split()[0])
    assert diff < 1e-4
    onnx_eval = runner.invoke(
        app,
        [
            *ev,
            "--onnx",
            str(onnx_path),
            "--out",
            str(tmp_path / "e2"),
            "--dump-scans",
            str(tmp_path / "scans"),
        ],
    )
    assert onnx_eval.exit_code == 0, onnx_eval.output
    r1, r2 = (json.loads((tmp_path / e / "report.json").read_text()) for e in ("e1", "e2"))
    assert np.allclose(r1["median_rotation_deg"], r2["median_rotation_deg"], atol=0.05)
    assert r1["scanner"] == r2["scanner"] == "surface"
    assert (tmp_path / "e1" / "anytime.png").stat().st_size > 10_000

    scans = sorted((tmp_path / "scans").glob("*.npy"))
    assert len(scans) == 6
    posed = runner.invoke(
        app,
        [
            "pose",
            *map(str, scans[:2]),
            "--model",
            "x",
            "--model-dir",
            str(onnx_path.parent),
            "--json",
            "--max-iterations",
            "3",
        ],
    )
    assert posed.exit_code == 0, posed.output
    # The engine (one pose request per file) gives the poses `itnet eval` computed in batches:
    # scans have fewer points than the model's count, and max-pooling ignores repeated points.
    eval_poses = np.load(tmp_path / "e2" / "poses.npz")["poses"]
    for i, line in enumerate(posed.stdout.splitlines()):
        pose = np.array(json.loads(line)["T_canonical_from_input"])
        assert np.allclose(pose, eval_poses[i, 3], atol=1e-4 * max(1.0, np.abs(pose).max()))

    # A recommended ensemble goes into the card only with its measurement (bench_ensemble's JSON).
    fused_path = tmp_path / "models" / "x3.onnx"
    fused = ["export", str(run / "best.pt"), "--out", str(fused_path), "--name", "x3",
             "--recommended-ensemble", "3"]  # fmt: skip
    refused = runner.invoke(app, fused)
    assert refused.exit_code == 2 and "--ensemble-report" in refused.output
    bench = {
        "machine": "test",
        "budget_ms": 20.0,
        "split": "test",
        "occluded": {
            "1": {"accuracy": 40.0, "gain": 0.0, "gain_stderr": 0.0, "scans": 9},
            "3": {"accuracy": 50.0, "gain": 10.0, "gain_stderr": 2.0, "scans": 9},
        },
    }
    (tmp_path / "bench.json").write_text(json.dumps(bench))  # fmt: skip
    wrong_k = runner.invoke(
        app, [*fused[:-1], "4", "--ensemble-report", str(tmp_path / "bench.json")]
    )
    assert wrong_k.exit_code == 2 and "does not measure 4 runs" in wrong_k.output
    done = runner.invoke(app, [*fused, "--ensemble-report", str(tmp_path / "bench.json")])
    assert done.exit_code == 0, done.output
    from itnet.pose.runtime import load_model

    card = load_model(fused_path, warm_up=False).card
    assert card.recommended_ensemble == 3
    assert "occluded 50.0% (one run 40.0%, +10.0 ± 2.0; 9 scans)" in card.ensemble_evaluation
    assert card.mirror is False  # a user's category declares no mirror symmetry unless told
    mirror_path = tmp_path / "models" / "xm.onnx"
    told = runner.invoke(
        app, ["export", str(run / "best.pt"), "--out", str(mirror_path), "--name", "xm",
              "--mirror-planes", "z,x"]
    )  # fmt: skip
    assert told.exit_code == 0, told.output
    assert load_model(mirror_path, warm_up=False).card.mirror_planes == ["z", "x"]
    wrong = runner.invoke(app, ["export", str(run / "best.pt"), "--out", str(mirror_path),
                                "--mirror-planes", "x,y"])  # fmt: skip
    assert wrong.exit_code == 2 and "--mirror-planes" in wrong.output


@pytest.mark.train
def test_compiled_training_matches_eager(shape_folder, tmp_path):
    """torch.compile changes the speed of a training step, not its numbers."""
    from itnet.model.optim import bn_momentum
    from itnet.model.train import TrainConfig, train

    losses = {}
    for compiled in (False, True):
        config = TrainConfig(
            data=shape_folder, category="x", frame="canonical", cache=tmp_path / "cache",
            out=tmp_path / f"run-{compiled}", steps=3, batch=8, points=64, iterations=2,
            eval_every=3, log_every=1, threads=1, bf16=False, compile=compiled,
        )  # fmt: skip
        train(config, resume=False, progress=False)
        log = (config.out / "log.jsonl").read_text().splitlines()
        losses[compiled] = [json.loads(line)["loss"] for line in log if '"loss"' in line]
    assert len(losses[True]) == 3
    assert np.allclose(losses[True], losses[False], rtol=1e-3), losses
    # BatchNorm momentum in stairs: a compiled network is specialised on it.
    stairs = {
        bn_momentum(config.bn_momentum, config.bn_decay_every, step)
        for step in range(0, 5 * config.bn_decay_every, 7)
    }
    assert sorted(stairs, reverse=True) == [0.5, 0.25, 0.125, 0.0625, 0.03125]


@pytest.mark.train
def test_data_workers_train_on_the_same_batches(shape_folder, tmp_path):
    """--data-workers makes the scans in other processes, ahead of the step: the same batches
    (each step's are seeded by the step), so the same losses as making them in the loop."""
    from itnet.model.train import TrainConfig, train

    losses = {}
    for workers in (0, 2):
        config = TrainConfig(
            data=shape_folder, category="x", frame="canonical", cache=tmp_path / "cache",
            out=tmp_path / f"run-{workers}", steps=4, batch=8, points=64, iterations=2,
            eval_every=4, log_every=1, threads=1, bf16=False, compile=False,
            data_workers=workers,
        )  # fmt: skip
        train(config, resume=False, progress=False)
        log = (config.out / "log.jsonl").read_text().splitlines()
        losses[workers] = [json.loads(line)["loss"] for line in log if '"loss"' in line]
    assert len(losses[2]) == 4
    assert np.allclose(losses[2], losses[0], rtol=1e-5), losses


def test_moving_average_of_weights():
    import torch

    from itnet.model.optim import average_of

    net = torch.nn.Sequential(torch.nn.Linear(2, 3), torch.nn.BatchNorm1d(3))
    assert average_of(net, 0) is None and average_of(net, None) is None
    ema = average_of(net, 0.75)
    ema.update_parameters(net)  # the first update copies
    weight = net[0].weight.detach().clone()
    with torch.no_grad():
        net[0].weight.add_(4.0)
    net.train()(torch.randn(8, 2))  # moves the BatchNorm statistics too
    ema.update_parameters(net)
    assert torch.allclose(ema.module[0].weight, weight + 1.0)  # 0.75 old + 0.25 new
    mean = ema.module[1].running_mean
    assert torch.allclose(mean, 0.25 * net[1].running_mean)  # from 0: averaged like weights


@pytest.mark.train
def test_loss_options_reach_the_training_step(shape_folder, tmp_path):
    """--loss distance and --supervise-last change the optimised loss (same seed, same scans:
    different losses at step 2; at step 1 every iteration is the identity, so only the kind of
    loss tells), are kept in config.json, and a bad --loss is refused."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.model.train import TrainConfig, train

    second = {}
    for loss, last in (("squared", 1), ("squared", 2), ("distance", 1)):
        config = TrainConfig(
            data=shape_folder, category="x", frame="canonical", cache=tmp_path / "cache",
            out=tmp_path / f"run-{loss}-{last}", steps=2, batch=8, points=64, iterations=2,
            eval_every=2, log_every=1, threads=1, bf16=False, compile=False, loss=loss,
            supervise_last=last,
        )  # fmt: skip
        train(config, resume=False, progress=False)
        log = (config.out / "log.jsonl").read_text().splitlines()
        second[loss, last] = [json.loads(line)["loss"] for line in log if '"loss"' in line][1]
        saved = json.loads((config.out / "config.json").read_text())
        assert (saved["loss"], saved["supervise_last"]) == (loss, last)
    assert all(np.isfinite(v) for v in second.values())
    assert len({round(v, 6) for v in second.values()}) == 3, second
    refused = CliRunner().invoke(app, ["train", "--loss", "cubic", "--out", str(tmp_path / "no")])
    assert refused.exit_code != 0 and "--loss must be one of" in refused.output
    for option, value, message in (
        ("--rotation", "euler", "--rotation must be one of"),
        ("--point-channels", "64,x", "positive integers"),
        ("--head-channels", "0", "positive integers"),
    ):
        refused = CliRunner().invoke(app, ["train", option, value, "--out", str(tmp_path / "no")])
        assert refused.exit_code != 0 and message in refused.output, refused.output


@pytest.mark.train
def test_6d_and_wider_networks_train_save_and_refuse_a_mismatched_init(shape_folder, tmp_path):
    """--rotation 6d and the widths reach the network, travel in the checkpoint (load_checkpoint
    rebuilds them), and fine-tuning from a checkpoint of another network is refused by name.
    Checkpoints from before the switch (no "rotation") read as the quaternion."""
    import pytest

    from itnet.model.train import TrainConfig, load_checkpoint, network_config, train

    common = dict(
        data=shape_folder, category="x", frame="canonical", cache=tmp_path / "cache", steps=2,
        batch=8, points=64, iterations=2, eval_every=2, threads=1, bf16=False, compile=False,
    )  # fmt: skip
    six = TrainConfig(
        **common, out=tmp_path / "six", rotation="6d", point_channels=(8, 16, 24),
        head_channels=(12,),
    )  # fmt: skip
    train(six, resume=False, progress=False)
    net, _ = load_checkpoint(six.out / "best.pt")
    assert net.config.rotation == "6d" and net.regressor.out.out_features == 9
    assert net.config.point_channels == (8, 16, 24) and net.config.head_channels == (12,)
    quaternion = TrainConfig(**common, out=tmp_path / "q", init_from=six.out / "best.pt")
    with pytest.raises(ValueError, match="is not this run's"):
        train(quaternion, resume=False, progress=False)
    old = {"point_channels": [64, 128, 1024], "head_channels": [512, 256], "identity_init": True}
    assert network_config(old).rotation == "quaternion"


@pytest.mark.train
def test_half_checkpoint_is_smaller_and_trains_on(shape_folder, tmp_path):
    """A checkpoint kept to go on from (float16 weights, no optimiser) loads back close to the
    float32 one and starts a fine-tune (--init-from reads it into float32)."""
    import torch

    from itnet.model.train import TrainConfig, load_checkpoint, ship_checkpoint, train

    common = dict(
        data=shape_folder, category="x", frame="canonical", cache=tmp_path / "cache", steps=2,
        batch=8, points=64, iterations=2, eval_every=2, threads=1, bf16=False, compile=False,
        point_channels=(16, 32, 64), head_channels=(32, 16),
    )  # fmt: skip
    first = TrainConfig(**common, out=tmp_path / "a")
    train(first, resume=False, progress=False)
    full = ship_checkpoint(first.out / "best.pt", tmp_path / "full.pt")
    half = ship_checkpoint(first.out / "best.pt", tmp_path / "half.pt", half=True)
    assert half.stat().st_size < 0.7 * full.stat().st_size
    (net_full, _), (net_half, state) = load_checkpoint(full), load_checkpoint(half)
    assert "optimizer" not in state
    assert all(v.dtype == torch.float16 for v in state["model"].values() if v.is_floating_point())
    for a, b in zip(net_full.state_dict().values(), net_half.state_dict().values()):
        assert b.dtype == a.dtype and torch.allclose(a.float(), b.float(), rtol=1e-2, atol=1e-3)
    again = TrainConfig(**common, out=tmp_path / "b", init_from=half)
    best = train(again, resume=False, progress=False)
    assert np.isfinite(best["val_accuracy"])


def test_upright_scans_keep_the_object_and_stand_it_up_within_the_error():
    """data.upright_scan: the levelled scan under its new pose lands where the scan did under
    its own (the same object), and the new pose's up (R^T e_y) is within the drawn error of
    +y; with no error it is +y exactly."""
    from itnet.geometry import apply_rigid, axis_angle_to_matrix
    from itnet.model.data import upright_scan

    rng = np.random.default_rng(5)
    for error in (0.0, 3.0):
        pose = np.eye(4)
        pose[:3, :3] = axis_angle_to_matrix(rng.normal(size=3), rng.uniform(0, np.pi))
        pose[:3, 3] = rng.normal(size=3)
        cloud = rng.normal(size=(50, 3)).astype(np.float32)
        levelled, moved = upright_scan(cloud, pose, error, rng)
        assert levelled.dtype == np.float32 and levelled.shape == cloud.shape
        np.testing.assert_allclose(
            apply_rigid(moved, levelled.astype(np.float64)), apply_rigid(pose, cloud), atol=1e-5
        )
        up = moved[1, :3]  # R^T e_y: the canonical up in the levelled scan's frame
        angle = np.degrees(np.arccos(np.clip(up[1], -1, 1)))
        assert angle == pytest.approx(error, abs=1e-4)


@pytest.mark.train
def test_an_upright_run_trains_on_levelled_scans_and_its_export_requires_up(shape_folder, tmp_path):
    """--upright: the training scans stand (their targets' up is +y within the error), the run
    trains and validates with it and keeps it in its config, and the export's card requires
    up."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.model.data import training_batch
    from itnet.model.scanner import scan_config
    from itnet.model.shapes import Shape
    from itnet.pose.runtime import load_model

    rng = np.random.default_rng(1)
    shapes = [Shape(f"s{i}", _chair_like(rng)) for i in range(3)]
    _, targets = training_batch(shapes, 16, 64, rng, scan_config({}), upright=4.0)
    ups = targets[:, 1, :3] / np.linalg.norm(targets[:, 1, :3], axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip(ups[:, 1], -1, 1))).max() < 4.0 + 1e-3
    _, free = training_batch(shapes, 16, 64, np.random.default_rng(1), scan_config({}))
    assert np.degrees(np.arccos(np.clip(free[:, 1, 1], -1, 1))).max() > 30  # anything, unlevelled

    run = tmp_path / "upright"
    done = CliRunner().invoke(app, [
        "train", "--data", str(shape_folder), "--category", "x", "--frame", "canonical",
        "--cache", str(tmp_path / "cache"), "--out", str(run), "--steps", "2", "--batch", "8",
        "--points", "64", "--iterations", "2", "--eval-every", "2", "--threads", "1",
        "--no-bf16", "--no-compile", "--ema", "0", "--upright", "5",
    ])  # fmt: skip
    assert done.exit_code == 0, done.output
    assert json.loads((run / "config.json").read_text())["upright"] == 5.0
    out = tmp_path / "x.onnx"
    exported = CliRunner().invoke(app, ["export", str(run / "best.pt"), "--out", str(out)])
    assert exported.exit_code == 0, exported.output
    card = load_model(out, threads=1).card
    assert card.requires_up and card.training["upright"] == 5.0


@pytest.mark.train
def test_widened_network_computes_the_narrow_ones_poses_and_trains_on(shape_folder, tmp_path):
    """model/widen.py: every hidden layer wider (point MLP and head), the same regressor output
    without noise (to float rounding), close with it, the copies made different by the noise;
    --init-from a narrower checkpoint with wider --point-channels / --head-channels starts from
    it widened, and a narrower or deeper run is still refused."""
    import pytest
    import torch

    from itnet.model.network import ITNet, NetworkConfig
    from itnet.model.train import TrainConfig, load_checkpoint, train
    from itnet.model.widen import can_widen, widen

    torch.manual_seed(0)
    narrow = ITNet(NetworkConfig((8, 16, 24), (12, 6)))
    for module in narrow.modules():  # trained-looking BatchNorm statistics and a non-zero output
        if isinstance(module, torch.nn.BatchNorm1d):
            module.running_mean.normal_()
            module.running_var.uniform_(0.5, 2.0)
            module.weight.data.uniform_(0.5, 1.5)
            module.bias.data.normal_()
    narrow.regressor.out.weight.data.normal_()
    narrow.eval()
    config = NetworkConfig((16, 20, 48), (24, 6))
    assert can_widen(narrow.config, config) and not can_widen(config, narrow.config)
    assert not can_widen(narrow.config, NetworkConfig((8, 16, 24, 32), (12, 6)))
    x = torch.randn(3, 50, 3)
    exact, noisy = widen(narrow, config, noise=0.0), widen(narrow, config, noise=0.01)
    reference = narrow.regressor(x)
    assert (
        exact.regressor.point_mlp[0].out_features == 16
        and exact.regressor.head[0].out_features == 24
    )
    assert torch.allclose(exact.regressor(x), reference, atol=1e-5)
    moved = (noisy.regressor(x) - reference).abs().max().item()
    assert 0 < moved < 0.05 * reference.abs().max().item()
    first = noisy.regressor.point_mlp[0].weight
    assert not torch.equal(first[8:], first[:8]) and torch.equal(
        exact.regressor.point_mlp[0].weight[8:], first[:8]
    )
    with pytest.raises(ValueError, match="cannot widen"):
        widen(exact, narrow.config)

    common = dict(
        data=shape_folder, category="x", frame="canonical", cache=tmp_path / "cache", steps=2,
        batch=8, points=64, iterations=2, eval_every=2, threads=1, bf16=False, compile=False,
    )  # fmt: skip
    small = TrainConfig(
        **common, out=tmp_path / "small", point_channels=(8, 16, 24), head_channels=(12,)
    )
    train(small, resume=False, progress=False)
    wide = TrainConfig(
        **common, out=tmp_path / "wide", point_channels=(16, 32, 24), head_channels=(24,),
        init_from=small.out / "best.pt", lr=0.0,
    )  # fmt: skip
    train(wide, resume=False, progress=False)
    (start, _), (widened, _) = (
        load_checkpoint(small.out / "best.pt"),
        load_checkpoint(wide.out / "last.pt"),
    )
    assert widened.config.point_channels == (16, 32, 24)
    assert torch.allclose(
        widened.regressor.point_mlp[0].weight[:8], start.regressor.point_mlp[0].weight
    )
    deeper = TrainConfig(**common, out=tmp_path / "deep", head_channels=(12, 6), point_channels=(8, 16, 24),
                         init_from=small.out / "best.pt")  # fmt: skip
    with pytest.raises(ValueError, match="is not this run's"):
        train(deeper, resume=False, progress=False)


def test_average_checkpoints_is_the_mean_of_one_networks_weights(tmp_path):
    """`itnet average`: the mean of every float tensor (weights and BatchNorm statistics), the
    counters and the config of the last checkpoint, loadable like any checkpoint; fewer than two
    checkpoints or checkpoints of different networks are refused with a clear message."""
    import dataclasses

    import torch
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.model.network import ITNet, NetworkConfig
    from itnet.model.train import load_checkpoint

    paths = []
    for seed, config in [(0, NetworkConfig((8, 16, 24), (12,))), (1, NetworkConfig((8, 16, 24), (12,))),
                         (2, NetworkConfig((8, 16, 32), (12,)))]:  # fmt: skip
        torch.manual_seed(seed)
        net = ITNet(config)
        net.regressor.point_mlp[1].running_mean.normal_()
        state = {"model": net.state_dict(), "network": dataclasses.asdict(config), "step": seed,
                 "config": {"category": "x"}, "metrics": {}, "optimizer": {"lr": 1}}  # fmt: skip
        paths.append(tmp_path / f"{seed}.pt")
        torch.save(state, paths[-1])
    runner = CliRunner()
    done = runner.invoke(
        app, ["average", str(paths[0]), str(paths[1]), "--out", str(tmp_path / "m.pt")]
    )
    assert done.exit_code == 0, done.output
    mean, state = load_checkpoint(tmp_path / "m.pt")
    a, b = (torch.load(p, weights_only=False)["model"] for p in paths[:2])
    for key, value in mean.state_dict().items():
        expected = (a[key] + b[key]) / 2 if a[key].is_floating_point() else b[key]
        assert torch.allclose(value, expected), key
    assert not torch.allclose(
        mean.state_dict()["regressor.point_mlp.1.running_mean"],
        a["regressor.point_mlp.1.running_mean"],
    )
    assert state["step"] == 1 and "optimizer" not in state and len(state["averaged_from"]) == 2
    for args, message in [([paths[0]], "at least two"), (paths, "different networks")]:
        refused = runner.invoke(app, ["average", *map(str, args), "--out", str(tmp_path / "x.pt")])
        assert refused.exit_code != 0 and message in refused.output, refused.output


def test_a_cache_file_appears_whole_or_not_at_all(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """save_npz (the shape and scan caches): the file is written under another name and renamed,
    so a process reading the cache while another writes it (parallel training
    jobs) never opens half a file; a write that fails leaves nothing under the cache's name."""
    from itnet.model import data as data_module

    path = tmp_path / "scans-abc.npz"
    data_module.save_npz(path, points=np.arange(6.0).reshape(2, 3))
    assert np.array_equal(np.load(path)["points"], np.arange(6.0).reshape(2, 3))
    assert [p.name for p in tmp_path.iterdir()] == ["scans-abc.npz"]  # no partial file left

    def half_written(out, **arrays):  # type: ignore[no-untyped-def]
        out.write(b"PK\x03\x04 half a zip")
        raise OSError("disk full")

    monkeypatch.setattr(data_module.np, "savez_compressed", half_written)
    other = tmp_path / "shapes-def.npz"
    with pytest.raises(OSError, match="disk full"):
        data_module.save_npz(other, points=np.zeros(3))
    assert not other.exists()  # a reader finds no cache and builds its own
    assert [p.name for p in tmp_path.iterdir()] == ["scans-abc.npz"]  # the partial is removed


def test_a_near_start_moves_a_scan_near_its_answer_and_keeps_its_canonical_points():
    """data.near_start: x' = E T x with E within the bounds (angle and shift both used up to
    their limits over many draws), and its target E^-1 takes x' to the same canonical points."""
    from itnet.geometry import apply_rigid, invert_rigid, random_rotation, rotation_angle_deg
    from itnet.model.data import near_start

    rng = np.random.default_rng(4)
    x = rng.normal(size=(64, 3)).astype(np.float32)
    angles, shifts = [], []
    for _ in range(300):
        target = np.eye(4)
        target[:3, :3], target[:3, 3] = random_rotation(rng), rng.normal(size=3)
        moved, near = near_start(x, target.astype(np.float32), rng, 15.0, 0.3)
        assert moved.dtype == x.dtype and near.dtype == np.float32
        assert np.allclose(apply_rigid(near, moved), apply_rigid(target, x), atol=1e-4)
        error = invert_rigid(near)
        angles.append(float(rotation_angle_deg(error[:3, :3])))
        shifts.append(float(np.linalg.norm(error[:3, 3])))
    assert max(angles) <= 15.0 + 1e-3 and max(angles) > 14.0 and min(angles) < 1.0
    assert max(shifts) <= 0.3 + 1e-5 and max(shifts) > 0.28


@pytest.mark.train
def test_near_starts_take_their_share_of_a_batch_and_a_run_records_them(shape_folder, tmp_path):
    """training_batch(near=...): that share of the scans has a target within the bounds of the
    identity (a fresh scan's is anything); ``itnet train --near-starts`` trains with them and
    keeps them in its config."""
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.geometry import rotation_angle_deg
    from itnet.model.data import NearStarts, training_batch
    from itnet.model.scanner import scan_config
    from itnet.model.shapes import Shape

    rng = np.random.default_rng(5)
    shapes = [Shape(f"s{i}", _chair_like(rng)) for i in range(3)]

    def angles(share: float) -> np.ndarray:
        near = NearStarts(share, max_deg=10.0, max_shift=0.1)
        _, targets = training_batch(
            shapes, 200, 64, np.random.default_rng(6), scan_config({}), near=near
        )
        return rotation_angle_deg(targets[:, :3, :3].astype(np.float64))

    assert (angles(1.0) <= 10.0 + 1e-3).all()
    near_share = (angles(0.5) <= 10.0 + 1e-3).mean()
    assert 0.35 < near_share < 0.65, near_share  # a fresh view is within 10° about 0.2% of times
    assert (angles(0.0) <= 10.0).mean() < 0.05

    run = tmp_path / "near"
    done = CliRunner().invoke(app, [
        "train", "--data", str(shape_folder), "--category", "x", "--frame", "canonical",
        "--cache", str(tmp_path / "cache"), "--out", str(run), "--steps", "2", "--batch", "8",
        "--points", "64", "--iterations", "2", "--eval-every", "2", "--threads", "1",
        "--no-bf16", "--no-compile", "--ema", "0", "--near-starts", "0.5", "--near-deg", "12",
    ])  # fmt: skip
    assert done.exit_code == 0, done.output
    config = json.loads((run / "config.json").read_text())
    assert (config["near_starts"], config["near_deg"], config["near_shift"]) == (0.5, 12.0, 0.2)
    refused = CliRunner().invoke(app, ["train", "--near-starts", "1.5", "--out", str(run)])
    assert refused.exit_code != 0 and "near-starts" in refused.output
