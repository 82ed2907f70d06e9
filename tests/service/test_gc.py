"""Start-up objects are frozen out of garbage collection, and GC passes are measured."""

from __future__ import annotations

import gc

from fastapi.testclient import TestClient

from itnet.service.app import create_app
from itnet.service.gc_tuning import GcPauseRecorder
from itnet.service.settings import Settings


def test_the_app_freezes_start_up_objects_and_reports_gc_pauses(tiny_model_dir) -> None:
    gc.unfreeze()
    try:
        settings = Settings(model_dir=tiny_model_dir, warm_up=False, gc_freeze=True)
        with TestClient(create_app(settings)) as client:
            assert gc.get_freeze_count() > 10_000  # the imports and the loaded model
            gc.collect()
            text = client.get("/metrics").text
        assert 'itnet_gc_pause_seconds_count{generation="2"}' in text
    finally:
        gc.unfreeze()


def test_freezing_is_a_setting(tiny_model_dir, monkeypatch) -> None:
    monkeypatch.setenv("ITNET_GC_FREEZE", "false")
    gc.unfreeze()
    with TestClient(create_app(Settings(model_dir=tiny_model_dir, warm_up=False))):
        assert gc.get_freeze_count() == 0


def test_pause_recorder_times_every_pass_and_can_be_removed() -> None:
    seen: list[tuple[int, float]] = []
    recorder = GcPauseRecorder(lambda generation, seconds: seen.append((generation, seconds)))
    recorder.install()
    recorder.install()  # once only
    try:
        gc.collect(1)
    finally:
        recorder.remove()
    assert seen == [(1, seen[0][1])] and 0 <= seen[0][1] < 1.0
    gc.collect()
    assert len(seen) == 1  # removed: no more reports
