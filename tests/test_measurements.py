"""A card's evaluation lines as typed measurements: read back exactly, rendered exactly."""

from __future__ import annotations

import pytest

from itnet.measurements import KINDS, Measurement
from itnet.model_card import ModelCard, describe_ensemble, describe_recheck, describe_up
from itnet.pose.runtime import default_model_dir, load_any


def test_every_shipped_line_reads_into_numbers_and_renders_back_exactly():
    read = 0
    for path in sorted(default_model_dir().glob("*.onnx")):
        card = load_any(path, warm_up=False).card
        if not isinstance(card, ModelCard):
            continue
        for kind in KINDS:
            line = getattr(card, f"{kind}_evaluation")
            if line:
                measured = card.measurement(kind)
                assert measured is not None and measured.text() == line, (path.name, kind)
                assert measured.results and all(0 <= r.accuracy <= 100 for r in measured.results)
                read += 1
    assert read >= 30


def _report(accuracy: float, runs: str = "1", **extra) -> dict:
    return {"machine": "x86_64, 2 cores", "budget_ms": 50.0, "split": "test",
            "paper": {runs: {"accuracy": accuracy, "stderr": 1.5, "gain": 2.5,
                             "gain_stderr": 0.8, "scans": 40, **extra}}}  # fmt: skip


def test_the_writers_lines_are_their_measurements():
    report = _report(80.0)
    report["paper"]["8"] = {"accuracy": 84.0, "stderr": 1.2, "gain": 4.0, "gain_stderr": 1.1,
                            "scans": 40}  # fmt: skip
    ensemble = Measurement.parse("ensemble", describe_ensemble(report, 8))
    row = ensemble.result("paper")
    assert (row.runs, row.accuracy, row.before, row.gain, row.gain_stderr, row.scans) == (
        8, 84.0, 80.0, 4.0, 1.1, 40)  # fmt: skip
    up = Measurement.parse("up", describe_up({**report, "up_error_deg": 2.0}, 8))
    assert up.up_error_deg == 2.0 and up.result("paper").stderr == 1.2
    with_it = _report(83.0, rechecked=0.25, versus_baseline={"gain": 3.0, "gain_stderr": 0.9})
    recheck = Measurement.parse("recheck", describe_recheck(_report(80.0), with_it))
    assert recheck.result("paper").share == 25.0 and recheck.result("paper").gain == 3.0
    with pytest.raises(KeyError):
        recheck.result("occluded")


def test_a_line_of_another_shape_has_no_measurement():
    with pytest.raises(ValueError):
        Measurement.parse("mirror", "measured by hand on a few scans")
    card = ModelCard(name="c", category="chair", mirror_evaluation="measured by hand")
    assert card.measurements == [] and card.measurement("mirror") is None
    line = describe_ensemble({**_report(80.0), "paper": {"1": _report(80.0)["paper"]["1"],
                              "8": {"accuracy": 84.0, "gain": 4.0, "gain_stderr": 1.1,
                                    "scans": 40}}}, 8)  # fmt: skip
    changed = card.model_copy(update={"ensemble_evaluation": line})
    assert [m.kind for m in changed.measurements] == ["ensemble"]  # read from the line, always


def test_every_shipped_pose_models_accuracy_protocol_reads_back_exactly():
    from itnet.measurements import AnytimeProtocol

    read = 0
    for path in sorted(default_model_dir().glob("*.onnx")):
        card = load_any(path, warm_up=False).card
        if isinstance(card, ModelCard):
            protocol = card.accuracy_protocol
            assert protocol is not None and protocol.text() == card.evaluation, path.name
            assert protocol.category == card.category and protocol.split == "test"
            read += 1
    assert read == 13
    with pytest.raises(ValueError):
        AnytimeProtocol.parse("measured on a few scans")
    assert ModelCard(name="c", category="chair", evaluation="by hand").accuracy_protocol is None
