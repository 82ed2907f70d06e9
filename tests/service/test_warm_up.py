"""Start-up warm-up: the batch sizes and point counts of the plans a request may get are run
before the first request, and only the single-run steps feed the step-time estimate."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from itnet.pose.runtime import load_model, warm_batches


class RecordingSession:
    """An onnxruntime session that records the batch size of every run (and runs it)."""

    def __init__(self, session) -> None:  # type: ignore[no-untyped-def]
        self.session, self.batches = session, []

    def run(self, outputs, feeds):  # type: ignore[no-untyped-def]
        self.batches.append(feeds["points"].shape[0])
        return self.session.run(outputs, feeds)


def test_warm_batches_cover_the_usual_ensembles_and_the_cards_halvings() -> None:
    assert warm_batches(1) == [2, 4, 8]
    assert warm_batches(8) == [2, 4, 8]
    assert warm_batches(16) == [2, 4, 8, 16]
    assert warm_batches(12) == [2, 3, 4, 6, 8, 12]  # 12 -> 6 -> 3: what fitting_ensemble runs


def test_warm_up_runs_every_batch_size_and_times_single_runs_only(tiny_model_dir: Path) -> None:
    model = load_model(tiny_model_dir / "tiny.onnx", warm_up=False)
    model.card = model.card.model_copy(update={"recommended_ensemble": 16})
    recording = RecordingSession(model.session)
    model.session = recording  # type: ignore[assignment]
    model.warm_up(runs=3)
    assert recording.batches[:3] == [1, 1, 1]
    assert sorted(set(recording.batches[3:])) == [2, 4, 8, 16]
    # two runs each, at a fused run's subset (0.8 of the card's points) and at the card's count
    assert all(recording.batches[3:].count(b) == 4 for b in (2, 4, 8, 16))
    assert len(model._recent) == 2  # the first step (lazy set-up) and the batches are not
    assert 0 < model.baseline_ms <= model.idle_ms <= model.step_ms * 2
    assert np.isfinite(model.predicted_step_ms())
