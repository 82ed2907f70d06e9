"""bench_ensemble's breakdown of the misses: near misses, wrong basins, centre-only misses."""

from __future__ import annotations

import numpy as np

from benchmarks.bench_ensemble import misses


def test_each_miss_is_counted_once_where_it_belongs() -> None:
    rot = np.array([3.0, 12.0, 19.9, 20.0, 170.0, 5.0, 9.9, 15.0])
    trans = np.array([0.01, 0.01, 0.5, 0.01, 0.5, 0.2, 0.1, 0.3])
    # right: scan 0; near misses: 1, 2, 7; wrong basins: 3, 4; centre only: 5, 6
    assert misses(rot, trans) == {
        "rot_10_20": 37.5, "rot_over_20": 25.0, "rot_over_135": 12.5, "centre_only": 25.0
    }  # fmt: skip
