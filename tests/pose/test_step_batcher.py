"""Steps of many runs in one call: batched while a call runs, never waiting for company."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from itnet.pose.catalog import Catalog
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import load_model
from itnet.pose.step_batcher import StepBatcher, _padded


class SlowStep:
    """A graph call that takes ``ms`` and adds each row's value to its pose (to check routing);
    the first call waits for ``gate`` where one is given (so others queue behind it)."""

    def __init__(self, ms: float, gate: threading.Event | None = None) -> None:
        self.ms, self.calls, self.gate = ms, [], gate
        self.entered = threading.Event()  # a call has begun

    def __call__(self, points, poses):
        self.entered.set()
        if self.gate is not None and not self.calls:
            self.gate.wait(5)
        self.calls.append(len(points))
        time.sleep(self.ms / 1e3)
        return poses + points[:, 0, 0][:, None, None], poses


def queue_behind_the_first(batcher: StepBatcher, step: SlowStep, submit, later) -> None:
    """Start ``submit(0)``; once its call holds the slot, start every ``later`` submission and
    open the first call when they all wait in the queue."""
    first = threading.Thread(target=submit, args=(0,))
    first.start()
    assert step.entered.wait(5)  # the first call holds the slot, at its gate
    rest = [threading.Thread(target=submit, args=args) for args in later]
    for t in rest:
        t.start()
    deadline = time.perf_counter() + 5
    while batcher.waiting < len(rest) and time.perf_counter() < deadline:
        time.sleep(0.001)
    assert step.gate is not None
    step.gate.set()
    for t in [first, *rest]:
        t.join(5)


def job(value: float, runs: int = 1, points: int = 8):
    return np.full((runs, points, 3), value, np.float32), np.zeros((runs, 4, 4), np.float32)


@pytest.mark.timing
def test_a_lone_step_runs_at_once():
    step = SlowStep(1.0)
    batcher = StepBatcher(step, lambda runs, points: 1.0)
    start = time.perf_counter()
    out, _ = batcher.step(*job(3.0), time.perf_counter() + 1.0)
    assert (time.perf_counter() - start) < 0.05 and step.calls == [1]
    assert np.all(out == 3.0) and (batcher.batches, batcher.jobs) == (1, 1)


def test_steps_that_arrive_during_a_call_share_the_next_and_each_gets_its_rows():
    step = SlowStep(1.0, threading.Event())
    batcher = StepBatcher(step, lambda runs, points: 1.0)
    results: dict[int, np.ndarray] = {}

    def submit(i: int) -> None:
        out, _ = batcher.step(*job(float(i), runs=2), time.perf_counter() + 5.0)
        results[i] = out

    queue_behind_the_first(batcher, step, submit, [(i,) for i in range(1, 6)])
    assert step.calls == [2, 10]  # the lone first job, then the five others in one call
    assert all(np.all(results[i] == i) and results[i].shape == (2, 4, 4) for i in range(6))


@pytest.mark.timing
def test_a_step_that_cannot_end_in_time_is_turned_away_and_batches_respect_deadlines():
    step = SlowStep(1.0, threading.Event())
    batcher = StepBatcher(step, lambda runs, points: 200.0 * runs)  # predicted: 200 ms a run
    assert batcher.step(*job(1.0), time.perf_counter() + 0.1) is None  # 200 ms > 100 ms
    assert step.calls == []
    late = {}
    # seconds from each submission: job 1 holds a call of one run (0.2 s), never of two (0.4 s)
    ends = {0: 10.0, 1: 0.35, 2: 10.0, 3: 10.0}

    def submit(i: int) -> None:
        late[i] = batcher.step(*job(float(i)), time.perf_counter() + ends[i])

    # behind the first call: one whose deadline holds a call of one run only, two with room
    queue_behind_the_first(batcher, step, submit, [(1,), (2,), (3,)])
    assert all(late[i] is not None for i in range(4))
    assert step.calls == [1, 1, 2]  # the first; the tight one alone; then the two together


def test_one_batching_run_at_a_time_gets_a_slot_to_itself():
    batcher = StepBatcher(SlowStep(1.0), lambda runs, points: 1.0)
    ran, value = batcher.exclusive(lambda: 42, time.perf_counter() + 1.0)
    assert (ran, value) == (True, 42)


def test_a_failing_call_fails_every_step_in_it():
    def broken(points, poses):
        raise RuntimeError("graph failed")

    batcher = StepBatcher(broken, lambda runs, points: 1.0)
    with pytest.raises(RuntimeError, match="graph failed"):
        batcher.step(*job(1.0), time.perf_counter() + 1.0)
    assert batcher.step.__self__ is batcher  # still usable: the slot was given back
    with pytest.raises(RuntimeError):
        batcher.step(*job(1.0), time.perf_counter() + 1.0)


def test_padding_by_repeats_leaves_a_step_as_it_was(tiny_model_dir):
    model = load_model(tiny_model_dir / "tiny.onnx", threads=1, warm_up=False)
    rng = np.random.default_rng(0)
    points = rng.normal(size=(3, 100, 3)).astype(np.float32)
    poses = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
    alone, _ = model.step(points, poses)
    padded, _ = model.step(_padded(points, 256), poses)
    assert np.allclose(alone, padded, atol=1e-6)


def test_requests_in_flight_together_get_the_poses_they_get_alone(tiny_model_dir, slow_copy):
    # each call sleeps 10 ms besides its work, so the requests' steps meet in the queue
    model = slow_copy(load_model(tiny_model_dir / "tiny.onnx", threads=1), 0.01, 1)
    catalog = Catalog({"tiny": model})
    rng = np.random.default_rng(1)
    clouds = [rng.normal(size=(n, 3)) * [0.3, 0.2, 0.1] for n in (100, 400, 400, 900, 2000, 60)]
    request = PoseRequest(budget_ms=10_000, model="tiny", ensemble=2, max_iterations=3)
    alone = [catalog.pose(c, request)["T_canonical_from_input"] for c in clouds]
    calls = model.batcher.batches
    together: dict[int, list] = {}
    barrier = threading.Barrier(len(clouds))

    def pose(i: int) -> None:
        barrier.wait()
        together[i] = catalog.pose(clouds[i], request)["T_canonical_from_input"]

    threads = [threading.Thread(target=pose, args=(i,)) for i in range(len(clouds))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert model.batcher.batches - calls < len(clouds) * 3  # steps shared calls
    for i in range(len(clouds)):
        assert np.allclose(together[i], alone[i], atol=1e-5)


def test_int8_graphs_share_no_call_and_the_provider_is_checked(tmp_path, export_model):
    from itnet.model_card import ModelCard
    from itnet.pose.runtime import ModelLoadError, RuntimeOptions, load_model

    for precision, jobs in (("float32", 8), ("int8", 1)):
        card = ModelCard(name=precision, category="chair", points=256, precision=precision)
        export_model(card, tmp_path / f"{precision}.onnx")
        model = load_model(tmp_path / f"{precision}.onnx", warm_up=False,
                           options=RuntimeOptions(batch_jobs=8))  # fmt: skip
        assert model.batcher.max_jobs == jobs
    with pytest.raises(ModelLoadError, match="unknown provider 'gpu'"):
        RuntimeOptions("gpu").providers()
    assert RuntimeOptions("cpu").providers() == ["CPUExecutionProvider"]
    import onnxruntime as ort

    if "CUDAExecutionProvider" not in ort.get_available_providers():
        with pytest.raises(ModelLoadError, match="lacks"):
            load_model(tmp_path / "int8.onnx", options=RuntimeOptions("cuda"))


def test_with_two_slots_every_step_is_served_once():
    step = SlowStep(5.0)
    batcher = StepBatcher(step, lambda runs, points: 5.0, slots=2)
    results: dict[int, np.ndarray] = {}

    def submit(i: int) -> None:
        out, _ = batcher.step(*job(float(i)), time.perf_counter() + 5.0)
        results[i] = out

    threads = [threading.Thread(target=submit, args=(i,)) for i in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert sorted(results) == list(range(12)) and sum(step.calls) == 12
    assert all(np.all(results[i] == i) for i in range(12)) and batcher.waiting == 0
