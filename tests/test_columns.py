"""``itnet.columns``: column-wise reductions and percentiles that give numpy's numbers."""

import numpy as np
import pytest

from itnet.columns import column_max, column_mean, column_min, percentiles


@pytest.mark.parametrize("n", [1, 2, 3, 50, 2001])
@pytest.mark.parametrize("q", [[98], [2, 98], [1, 99], [0, 100], [50]])
def test_percentiles_are_numpys_to_the_bit(n: int, q: list[float]) -> None:
    rng = np.random.default_rng(n)
    line, tall, wide = rng.normal(size=n), rng.normal(size=(n, 2)), rng.normal(size=(3, n))
    assert np.array_equal(percentiles(line, q), np.percentile(line, q))
    assert np.array_equal(percentiles(tall, q), np.percentile(tall, q, axis=0))
    assert np.array_equal(percentiles(wide, q, axis=1), np.percentile(wide, q, axis=1))


def test_column_reductions_are_numpys() -> None:
    points = np.random.default_rng(0).normal(size=(1000, 3))
    assert np.array_equal(column_min(points), points.min(axis=0))
    assert np.array_equal(column_max(points), points.max(axis=0))
    assert np.allclose(column_mean(points), points.mean(axis=0))
