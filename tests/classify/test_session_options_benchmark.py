"""benchmarks/session_options.py: one graph timed under each option set, a pose step (which
takes a pose) and a classifier (which does not)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from benchmarks.session_options import OPTIONS, main, options


def test_each_option_set_is_timed_on_pose_steps_and_classifiers(
    chair_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for graph, points in (("chair.onnx", 128), ("classifier.onnx", 64)):
        argv = ["session_options", str(chair_dir / graph), "--points", str(points)]
        monkeypatch.setattr(sys, "argv", [*argv, "--blocks", "2", "--calls", "3"])
        main()
        result = json.loads(capsys.readouterr().out)
        assert result["calls"] == 6 and list(result["options"]) == list(OPTIONS)
        for measured in result["options"].values():
            assert 0 < measured["median_ms"] <= measured["p90_ms"]
            assert measured["cpu_ms_per_call"] > 0


def test_spinning_only_during_a_run_is_a_session_config_entry() -> None:
    made = options(2, spinning=True, stop=True)
    assert made.intra_op_num_threads == 2
    assert made.get_session_config_entry("session.intra_op.allow_spinning") == "1"
    assert made.get_session_config_entry("session.force_spinning_stop") == "1"
    assert options(1).get_session_config_entry("session.intra_op.allow_spinning") == "0"
