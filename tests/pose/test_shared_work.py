"""Worker processes admit one machine's worth together: each publishes its admitted runs and
their work in a shared file, and each admission counts the others'."""

from __future__ import annotations

import multiprocessing
import os
from pathlib import Path

import pytest

from itnet.pose.admission import Admission
from itnet.pose.catalog import Catalog
from itnet.pose.errors import OverloadedError
from itnet.pose.request import PoseRequest
from itnet.pose.shared_work import SHARED_ADMISSION_ENV, SharedWork


def _other_process(path: str, runs: int, work_ms: float, ready, done) -> None:
    """Another worker: publishes ``runs`` admitted runs needing ``work_ms``, then waits."""
    shared = SharedWork(Path(path))
    shared.publish(runs, work_ms)
    ready.set()
    done.wait(30)
    shared.publish(0, 0.0)


def _another(path: Path, runs: int, work_ms: float):
    context = multiprocessing.get_context("spawn")
    ready, done = context.Event(), context.Event()
    process = context.Process(target=_other_process, args=(str(path), runs, work_ms, ready, done))
    process.start()
    assert ready.wait(60)
    return process, done


def test_each_process_sees_the_others_work_and_a_dead_ones_is_forgotten(tmp_path: Path) -> None:
    path = tmp_path / "admitted"
    here = SharedWork(path)
    here.publish(1, 5.0)
    assert here.others() == (0, 0.0)  # its own record is not another's
    process, done = _another(path, 3, 120.0)
    assert here.others() == (3, 120.0)
    done.set()
    process.join(30)
    assert here.others() == (0, 0.0)  # it let go of its runs

    process, _ = _another(path, 2, 80.0)
    assert here.others() == (2, 80.0)
    process.kill()  # a worker killed with runs in flight
    process.join(30)
    assert here.others() == (0, 0.0)
    again = SharedWork(path, pid=process.pid)  # its record is free again
    assert again.slot != here.slot
    here.close()


def test_a_run_is_refused_where_another_processs_work_leaves_no_room(
    tmp_path: Path, model, cloud
) -> None:
    path = tmp_path / "admitted"
    catalog = Catalog({"tiny": model}, admission=Admission(shared=SharedWork(path)))
    request = PoseRequest(budget_ms=200, max_iterations=3)
    process, done = _another(path, 4, 10_000.0)  # another worker's runs need 10 s of steps
    try:
        with pytest.raises(OverloadedError, match="4 estimate"):
            catalog.pose(cloud, request)
    finally:
        done.set()
        process.join(30)
    assert catalog.pose(cloud, request)["iterations"] == 3  # the machine is free again
    run = catalog.start(cloud, request)
    with catalog.serving(run):  # while it runs, the others see it
        other = SharedWork(path, pid=1)  # pid 1: a live process that is not this one
        assert other.others() == (1, pytest.approx(run.needed_work_ms(), rel=0.5))
        run.run_to_end()
    assert SharedWork(path, pid=1).others() == (0, 0.0)


def test_serving_with_workers_names_one_shared_file_for_all_of_them(monkeypatch) -> None:
    import uvicorn

    from itnet.service.server import run
    from itnet.service.settings import Settings

    seen: dict[str, str | None] = {}

    def fake_run(*args, **kwargs) -> None:
        seen["path"] = os.environ.get(SHARED_ADMISSION_ENV)
        seen["workers"] = kwargs.get("workers")
        SharedWork.from_env()  # a worker can open it

    monkeypatch.setattr(uvicorn, "run", fake_run)
    monkeypatch.delenv(SHARED_ADMISSION_ENV, raising=False)
    run(Settings(), workers=2)
    assert seen["workers"] == 2 and seen["path"]
    assert not Path(seen["path"]).exists()  # removed when the server stops
    assert SHARED_ADMISSION_ENV not in os.environ
