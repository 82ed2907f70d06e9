"""StreamDrain: the stream runs in flight are cancelled on SIGTERM, then uvicorn gets the signal."""

import signal
import threading
import time

from itnet.service.draining import StreamDrain


class FakeRun:
    def __init__(self) -> None:
        self.cancelled = threading.Event()

    def cancel(self) -> None:
        self.cancelled.set()


def test_begin_cancels_runs_in_flight_and_later_ones():
    drain = StreamDrain()
    first, late = FakeRun(), FakeRun()
    with drain.track(first):
        assert drain.in_flight() == 1 and not first.cancelled.is_set()
        drain.begin()
        assert first.cancelled.is_set() and drain.draining.is_set()
        with drain.track(late):
            assert late.cancelled.is_set()  # shutdown had begun: cancelled at once
    assert drain.in_flight() == 0 and drain.wait_idle(0.0)


def test_the_installed_handler_hands_the_signal_over_once_streams_are_done():
    drain = StreamDrain(grace_s=5.0)
    handed: list[float] = []
    original = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, lambda signum, frame: handed.append(time.monotonic()))
    try:
        assert drain.install()
        run = FakeRun()
        with drain.track(run):
            signal.getsignal(signal.SIGTERM)(signal.SIGTERM, None)
            assert run.cancelled.wait(1.0)
            time.sleep(0.1)
            assert handed == []  # the stream has not answered yet
            finished = time.monotonic()
        deadline = time.monotonic() + 2.0
        while not handed and time.monotonic() < deadline:
            time.sleep(0.01)
        assert handed and handed[0] >= finished  # handed over after the stream was done
    finally:
        signal.signal(signal.SIGTERM, original)


def test_install_needs_the_main_thread():
    out: list[bool] = []
    thread = threading.Thread(target=lambda: out.append(StreamDrain().install()))
    thread.start()
    thread.join()
    assert out == [False]
