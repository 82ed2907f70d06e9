"""itnet.metrics.paired_accuracy: the accuracy and paired-gain figures every benchmark prints."""

from __future__ import annotations

import math

import numpy as np

from itnet.metrics import paired_accuracy


def test_paired_accuracy_against_a_hand_count() -> None:
    baseline = np.array([1, 0, 0, 1, 0, 1, 0, 0], float)  # 3 of 8
    method = np.array([1, 1, 0, 1, 1, 0, 0, 1], float)  # 5 of 8: +3 -1 on the same scans
    row = paired_accuracy(method, baseline)
    assert row["scans"] == 8
    assert row["accuracy"] == 62.5
    assert row["stderr"] == round(100 * math.sqrt(0.625 * 0.375 / 8), 1)  # 17.1
    assert row["gain"] == 25.0
    diff = method - baseline  # +1 three times, -1 once, 0 four times: mean 0.25
    spread = math.sqrt(((diff - 0.25) ** 2).mean())
    assert row["gain_stderr"] == round(100 * spread / math.sqrt(8), 1)
    same = paired_accuracy(baseline, baseline)
    assert (same["gain"], same["gain_stderr"], same["accuracy"]) == (0.0, 0.0, 37.5)
