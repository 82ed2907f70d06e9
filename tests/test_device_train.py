"""scripts/device_train.py at toy scale on the CPU: calibration, the planned second run inside the
budget, and the shipped checkpoint, log and config in the tar file."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "device_train.py"
BUDGET = 60
CALIBRATION = 75


def _run(
    command: list[str], timeout: float, cwd: Path | None = None
) -> subprocess.CompletedProcess:
    """``command`` run as a job runs here: one OpenMP thread a process (2 cores), its output
    captured."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        command, env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def _job_args(tmp_path: Path, **overrides: object) -> argparse.Namespace:
    """A job's command line as ``job_config`` / ``classifier_config`` read it: as on a lease
    (cuda, 2 data workers, full size), with ``overrides``."""
    fields = {"init_dir": None, "lr": None, "tiny": False, "data": tmp_path / "data",
              "work": tmp_path / "work", "device": "cuda", "data_workers": 2}  # fmt: skip
    return argparse.Namespace(**{**fields, **overrides})


def _tub(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """A noisy open-top box, long along x, z up (ModelNet's frame): the bathtubs' orientation
    check (0 or 90 degrees about up) tells its turns apart."""
    size = np.array([1.0, 0.45, 0.35]) * rng.uniform(0.9, 1.1, size=3)
    face = rng.integers(5, size=n)  # -x, +x, -y, +y, bottom
    points = rng.uniform(-1, 1, size=(n, 3))
    points[np.arange(n), np.array([0, 0, 1, 1, 2])[face]] = np.array([-1, 1, -1, 1, -1])[face]
    return points * size + rng.normal(0, 0.005, size=(n, 3))


@pytest.mark.slow
def test_run_calibrates_plans_trains_and_packs(tmp_path: Path) -> None:
    from modelnet_tree import write_modelnet_tree

    from itnet.model.cloud_pack import pack

    rng = np.random.default_rng(0)
    data, work, out = tmp_path / "data", tmp_path / "work", tmp_path / "out"
    # the clouds travel as the machine gets them: a pack of the training split alone
    write_modelnet_tree(tmp_path / "source", {"bathtub": _tub}, rng, train=12, test=3)
    pack(tmp_path / "source", ["bathtub"], tmp_path / "train.xz", splits=("train",))
    command = [sys.executable, str(SCRIPT), "run", "--device", "cpu", "--tiny"]
    command += ["--pack", str(tmp_path / "train.xz"), "--data", str(data)]
    command += ["--work", str(work), "--out", str(out)]
    command += ["--budget", str(BUDGET), "--jobs", "bathtub"]
    command += ["--calibration-steps", str(CALIBRATION), "--data-workers", "1"]
    # --margin: the default (30 s, for packing eight jobs) would leave a 40 s budget no time
    # after the calibration for the planned run
    command += ["--restart-s", "5", "--validation-s", "1", "--margin", "5"]
    done = _run(command, BUDGET + 60, cwd=tmp_path)
    output = (
        done.stdout
        + done.stderr
        + ((work / "bathtub.out").read_text() if (work / "bathtub.out").exists() else "")
    )
    assert done.returncode == 0, output

    summary = json.loads((out / "summary.json").read_text())
    assert summary["device"] == "cpu" and summary["budget_s"] == BUDGET
    assert summary["wall_s"] <= BUDGET + 10, summary  # stopped at the budget's end
    job = summary["jobs"]["bathtub"]
    assert job["rate_steps_per_s"] > 0, summary
    assert job["steps"] > CALIBRATION, summary  # the second run was planned ...
    assert job["exit"] in (0, 143), output  # ... and finished or was stopped at the deadline
    assert CALIBRATION < job["steps_done"] <= job["steps"], summary
    assert job["best_step"] is not None and job["val_curve"][0][0] == CALIBRATION

    with tarfile.open(out / "runs-1.tar") as tar:
        names = set(tar.getnames())
        assert {"bathtub/best.pt", "bathtub/log.jsonl", "bathtub/config.json"} <= names, names
        tar.extractall(tmp_path / "shipped", filter="data")
    shipped = tmp_path / "shipped" / "bathtub"

    from itnet.model.train import load_checkpoint

    net, state = load_checkpoint(shipped / "best.pt")
    assert "optimizer" not in state  # shipped without it
    assert state["step"] == job["best_step"]
    assert tuple(net.config.point_channels) == (16, 32, 64)  # the --tiny network
    config = json.loads((shipped / "config.json").read_text())
    assert config["category"] == "bathtub" and config["steps"] == job["steps"]
    assert config["batch"] == 8 and config["data_workers"] == 1
    log = [json.loads(line) for line in (shipped / "log.jsonl").read_text().splitlines()]
    assert max(e.get("step", 0) for e in log) == job["steps_done"]
    assert [e["step"] for e in log if e.get("event") == "start"] == [0, CALIBRATION]  # resumed


def _ball(rng: np.random.Generator, n: int = 300) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.slow
def test_the_classifier_job_trains_from_a_training_only_pack(tmp_path: Path) -> None:
    """--jobs classifier shared: a pack without the test split (what travels to the machine)
    unpacks, the classifier and the shared pose network (an experiment, never a default job)
    train on every class folder, and their shipped checkpoints come back."""
    from modelnet_tree import write_modelnet_tree

    from itnet.model.classify.train import load_classifier
    from itnet.model.cloud_pack import pack

    rng = np.random.default_rng(1)
    source, work, out = tmp_path / "source", tmp_path / "work", tmp_path / "out"
    write_modelnet_tree(source, {"bathtub": _tub, "ball": _ball}, rng, train=10, test=2)
    pack(source, ["bathtub", "ball"], tmp_path / "train.xz", splits=("train",))
    budget = 45
    command = [sys.executable, str(SCRIPT), "run", "--device", "cpu", "--tiny"]
    command += ["--pack", str(tmp_path / "train.xz"), "--data", str(tmp_path / "data")]
    command += ["--work", str(work), "--out", str(out), "--budget", str(budget)]
    command += ["--jobs", "classifier", "shared", "--calibration-steps", "40"]
    command += ["--data-workers", "0"]
    command += ["--restart-s", "5", "--validation-s", "1", "--margin", "5"]
    done = _run(command, budget + 60, cwd=tmp_path)
    log = work / "classifier.out"
    assert done.returncode == 0, (
        done.stdout + done.stderr + (log.read_text() if log.exists() else "")
    )
    job = json.loads((out / "summary.json").read_text())["jobs"]["classifier"]
    assert job["rate_steps_per_s"] > 0 and job["steps"] > 40, job  # a second run was planned
    assert job["steps_done"] > 40 and job["best_val_mean_class"] is not None, job
    with tarfile.open(out / "runs-1.tar") as tar:
        tar.extractall(tmp_path / "shipped", filter="data")
    net, state = load_classifier(tmp_path / "shipped" / "classifier" / "best.pt")
    assert "optimizer" not in state and state["classes"] == ["ball", "bathtub"]
    assert state["step"] == job["best_step"] and net.config.point_channels == (16, 32, 64)
    shared = json.loads((out / "summary.json").read_text())["jobs"]["shared"]
    assert shared["steps_done"] > 40 and shared["best_val_accuracy"] is not None, shared
    config = json.loads((tmp_path / "shipped" / "shared" / "config.json").read_text())
    assert config["category"] == "modelnet10" and config["lr"] == 1e-3  # every class, scratch


def test_a_job_killed_by_the_deadline_counts_as_stopped_and_a_crash_does_not() -> None:
    """_exit_code: a job that dies of the driver's SIGTERM (-15, e.g. while its interpreter
    shuts down and its handler is gone) reads 143, as a job whose handler exits 143 does; any
    other failure keeps its own status, so the summary still shows a crash as one."""
    import signal

    driver = _script_module()
    killed = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    killed.send_signal(signal.SIGTERM)
    killed.wait(10)
    assert killed.returncode == -signal.SIGTERM and driver._exit_code(killed) == 143
    crashed = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    crashed.wait(10)
    assert driver._exit_code(crashed) == 3


def _script_module():  # type: ignore[no-untyped-def]
    import importlib.util

    spec = importlib.util.spec_from_file_location("device_train", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _tiny_job(name: str, data: Path, work: Path, steps: int) -> None:
    """``device_train.py job --name NAME --tiny`` on the CPU for ``steps`` steps (the rate
    decayed every half of them); fails the test with the job's output if the job fails."""
    command = [sys.executable, str(SCRIPT), "job", "--name", name, "--tiny", "--device", "cpu"]
    command += ["--steps", str(steps), "--decay-every", str(steps // 2), "--data-workers", "0"]
    command += ["--data", str(data), "--work", str(work)]
    done = _run(command, 300)
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_local_head_job_trains_behind_the_shipped_canonicaliser_frozen(tmp_path: Path) -> None:
    """classifier_local: as served, the local head behind the shipped classifier's canonicaliser
    (an absolute path in the repository), frozen, 96 canonical points; the --tiny check trains
    a small one (the shipped canonicaliser is full size) and its checkpoint is a local head."""
    from modelnet_tree import write_modelnet_tree

    from itnet.model.classify.train import load_classifier

    device_train = _script_module()
    args = _job_args(tmp_path)
    config = device_train.classifier_config("classifier_local", args, 1000, 150)
    assert config.head == "local" and config.freeze_transformer and config.canonical_points == 96
    assert config.transformer_from == SCRIPT.parents[1] / "itnet/models/classifier.pt"
    assert config.transformer_from.exists() and config.init_from is None and config.batch == 100
    assert config.out == tmp_path / "work" / "runs" / "classifier_local"
    assert {"classifier_local", "classifier_scratch"} <= set(device_train.JOB_NAMES)
    scratch = device_train.classifier_config("classifier_scratch", args, 1000, 150)
    assert scratch.init_from is None and scratch.transformer_from is None  # from scratch
    assert scratch.balanced and scratch.batch == 100 and scratch.canonical_points == 96
    assert scratch.head == "pointnet" and scratch.variant == "itnet-2" and scratch.ema == 0.999

    rng = np.random.default_rng(3)
    write_modelnet_tree(tmp_path / "data", {"bathtub": _tub, "ball": _ball}, rng, train=8, test=0)
    _tiny_job("classifier_local", tmp_path / "data", tmp_path / "work", 20)
    net, state = load_classifier(tmp_path / "work" / "runs" / "classifier_local" / "best.pt")
    assert net.config.head == "local" and net.config.local_channels == (8, 8, 16)
    assert state["classes"] == ["ball", "bathtub"]


def test_the_heads_go_on_behind_the_shipped_canonicaliser_so_they_still_fuse(
    tmp_path: Path,
) -> None:
    """classifier_head_ft / classifier_local_ft (the next lease's plan): each shipped head goes on
    from its shipped weights with the canonicaliser frozen, which is what lets ``classify-export
    --fuse-with`` fuse the two after; the --tiny check trains a small local head so."""
    from modelnet_tree import write_modelnet_tree

    from itnet.model.classify.train import load_classifier

    device_train = _script_module()
    args = _job_args(tmp_path)
    models = SCRIPT.parents[1] / "itnet" / "models"
    head = device_train.classifier_config("classifier_head_ft", args, 1000, 150)
    local = device_train.classifier_config("classifier_local_ft", args, 1000, 150)
    assert head.init_from == models / "classifier.pt" and head.head == "pointnet"
    assert local.init_from == models / "classifier_local.pt" and local.head == "local"
    for config in (head, local):
        assert config.freeze_transformer and config.canonical_points == 96 and config.balanced
        assert config.init_from is not None and config.init_from.exists()
        assert config.lr < 1e-3 and config.ema == 0.999 and config.batch == 100

    rng = np.random.default_rng(5)
    write_modelnet_tree(tmp_path / "data", {"bathtub": _tub, "ball": _ball}, rng, train=8, test=0)
    _tiny_job("classifier_local_ft", tmp_path / "data", tmp_path / "work", 10)
    net, _ = load_classifier(tmp_path / "work" / "runs" / "classifier_local_ft" / "best.pt")
    assert net.config.head == "local"


def test_the_chair_from_scratch_job_is_the_shipped_recipe_at_the_papers_batch(
    tmp_path: Path,
) -> None:
    """chair_scratch (issue 11's next lease): the chair from scratch (no starting weights), the
    shipped recipe's precision loss and moving average, the paper's rate and batch."""
    device_train = _script_module()
    args = _job_args(tmp_path)
    config = device_train.job_config("chair_scratch", args, 1000, 150)
    assert config.category == "chair" and config.init_from is None and config.lr == 1e-3
    assert config.loss == "distance" and config.ema == 0.999 and config.batch == 100
    assert config.bn_momentum == (0.5, 0.01) and "chair_scratch" in device_train.JOB_NAMES
    assert "chair_scratch" not in device_train.JOBS  # run only when --jobs names it
    near = device_train.job_config("chair_scratch_near", args, 1000, 150)
    assert near.near_starts == 0.3 and config.near_starts == 0.0  # its arm: one change apart
    differ = {k for k, v in near.model_dump().items() if v != config.model_dump()[k]}
    assert differ == {"near_starts", "out"}, differ


def test_the_table_rows_get_the_same_steps_and_are_measured_here(tmp_path: Path) -> None:
    """table_VARIANT: the paper's table, a job a row (shapes drawn uniformly, from scratch), the
    same steps each (the slowest row's plan); ``table`` here measures a returned row on the test
    split, which the machine never had, and writes the table's report."""
    from modelnet_tree import write_modelnet_tree

    device_train = _script_module()
    plans = {"table_none": {"steps": 900}, "table_itnet-2": {"steps": 500}, "chair": {"steps": 700}}
    device_train.equal_table_steps(plans)
    assert [p["steps"] for p in plans.values()] == [500, 500, 700]
    from itnet.model.classify.network import VARIANTS

    assert tuple(VARIANTS) == device_train.TABLE_VARIANTS  # written out there: the same rows
    assert {f"table_{v}" for v in device_train.TABLE_VARIANTS} <= set(device_train.JOB_NAMES)
    row = device_train.CLASSIFIER_JOBS["table_tnet-reg-2"]
    assert row["variant"] == "tnet-reg-2" and not row["balanced"] and "init_from" not in row

    rng = np.random.default_rng(4)
    write_modelnet_tree(tmp_path / "data", {"bathtub": _tub, "ball": _ball}, rng, train=8, test=2)
    work = tmp_path / "work"
    _tiny_job("table_none", tmp_path / "data", work, 20)
    # as returned from a lease: another machine's paths in the checkpoint's config
    (work / "runs" / "table_none" / "result.json").unlink()
    moved = tmp_path / "returned"
    (work / "runs").rename(moved)
    (tmp_path / "data").rename(tmp_path / "data_here")  # the config's data is gone
    lease = {"device": "cuda", "gpu": "NVIDIA H200", "torch": "2.11.0", "jobs": {
        "table_none": {"steps_done": 20}, "classifier_local": {"steps_done": 5}}}  # fmt: skip
    (moved / "summary.json").write_text(json.dumps(lease))
    command = [sys.executable, str(SCRIPT), "table", "--runs", str(moved)]
    command += ["--out", str(tmp_path / "rows"), "--data", str(tmp_path / "data_here")]
    command += ["--cache", str(tmp_path / "cache"), "--docs", str(tmp_path / "docs")]
    done = _run(command, 300)
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads((tmp_path / "rows" / "none" / "result.json").read_text())
    assert result["variant"] == "none" and result["test"]["scans"] == 2 * 2 * 4
    # the remade run's weights carry the config of here, so weights shipped from it export here
    from itnet.model.classify.train import load_classifier

    remade = load_classifier(tmp_path / "rows" / "none" / "best.pt")[1]["config"]
    assert remade["data"] == str(tmp_path / "data_here") and remade["device"] == "cpu"
    assert remade == json.loads((tmp_path / "rows" / "none" / "config.json").read_text())
    page = (tmp_path / "docs" / "classification.md").read_text()
    assert "| none |" in page and "one leased NVIDIA H200 shared by 2 processes" in page
    assert "batch 100, 20 steps a row" in page  # the rows' steps, not the other job's
    assert (tmp_path / "docs" / "confusion_table.png").exists()


def test_results_come_back_in_tar_files_the_device_returns() -> None:
    """tar_groups: every job once, in order, in tar files under 15 MiB (the device tool returns
    files of 16 MiB at most, 8 in all); session 30's seven table rows of 6.4 MB went four a tar
    (23 MB) and did not come back."""
    device_train = _script_module()
    mb = 2**20
    rows = {f"table_{v}": int(6.4 * mb) for v in device_train.TABLE_VARIANTS}
    groups = device_train.tar_groups(rows)
    assert [n for group in groups for n in group] == list(rows)
    assert all(sum(rows[n] for n in group) <= device_train.TAR_LIMIT for group in groups)
    assert len(groups) + 1 <= 8  # with summary.json
    assert device_train.tar_groups({"big": 20 * mb, "a": mb, "b": mb}) == [["big"], ["a", "b"]]


def test_a_job_that_fails_to_load_does_not_hold_the_others(tmp_path: Path) -> None:
    """_barrier: a job whose data fails to load marks itself as ready before it fails, so that
    the jobs waiting for every name start stepping instead of waiting out the calibration's
    deadline (session 30's first two calls lost every job that way)."""
    import time

    device_train = _script_module()
    args = _job_args(tmp_path, tiny=True, data=tmp_path / "missing", device="cpu", data_workers=0)
    config = device_train.classifier_config("table_none", args, 10, 5)
    ready = tmp_path / "ready"
    started = time.monotonic()
    with pytest.raises(FileNotFoundError):
        device_train._barrier(config, "table_none", ["table_none", "table_itnet-2"], ready)
    assert (ready / "table_none").exists()
    assert time.monotonic() - started < 60  # it failed at once, not after the barrier's wait
