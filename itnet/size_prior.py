"""A known unit makes size a clue to the category: a night stand is smaller than a dresser.

Pure numpy. The classifier sees clouds normalised to unit RMS radius (``itnet.preprocess``), so it
cannot tell a small object from a large one of the same form. When a request says its cloud's
unit, the cloud's RMS radius about its centroid in metres, ``r``, gives each class c a size
log-likelihood from the classifier card's :class:`~itnet.model_card.SizePrior` (a Student-t over
``log r``, heavy-tailed so that one odd size does not overrule the shape), and::

    log p(c | cloud, size) = log p(c | cloud) + weight * log p(log r | c) + const

renormalised over the classes.
"""

from __future__ import annotations

from typing import Literal, get_args

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.model_card import SizePrior

Unit = Literal["m", "cm", "mm", "in", "ft"]  # the units a request may name
METRES_PER_UNIT: dict[str, float] = dict(zip(get_args(Unit), (1.0, 0.01, 0.001, 0.0254, 0.3048)))


def metres_per_unit(unit: str) -> float:
    """'m', 'cm', 'mm', 'in' or 'ft' -> metres per unit. Raises ValueError for another name."""
    try:
        return METRES_PER_UNIT[unit]
    except KeyError:
        raise ValueError(f"unknown unit {unit!r}; one of {', '.join(METRES_PER_UNIT)}") from None


def log_student_t(
    log_x: float, log_median: ArrayLike, log_scale: ArrayLike, df: float
) -> NDArray[np.float64]:
    """log p(log x | class) (C,) under each class's Student-t over log x (median and scale (C,)),
    up to a constant shared by the classes: heavy-tailed, so one odd size weighs little."""
    median, scale = np.asarray(log_median, np.float64), np.asarray(log_scale, np.float64)
    z = (log_x - median) / scale
    return -(df + 1) / 2 * np.log1p(z**2 / df) - np.log(scale)


def log_median_and_spread(log_values: ArrayLike) -> tuple[float, float]:
    """Logs of sizes (V,) -> their median and a robust spread (1.4826 x the median absolute
    deviation), robust to the share of a dataset's models drawn at another scale."""
    log_v = np.asarray(log_values, np.float64)
    median = float(np.median(log_v))
    return median, 1.4826 * float(np.median(np.abs(log_v - median)))


def size_log_likelihood(prior: SizePrior, rms_radius_m: float) -> NDArray[np.float64]:
    """log p(log r | class) (C,) of a cloud whose RMS radius about its centroid is ``rms_radius_m``
    metres, up to a constant shared by the classes."""
    return log_student_t(
        float(np.log(max(rms_radius_m, 1e-9))), prior.log_median, prior.log_scale, prior.df
    )


def with_size(log_probs: ArrayLike, prior: SizePrior, rms_radius_m: float) -> NDArray[np.float64]:
    """A classifier's log-probabilities (C,) -> those given the size too (C,), unnormalised."""
    return np.asarray(log_probs, np.float64) + prior.weight * size_log_likelihood(
        prior, rms_radius_m
    )


def fit_size_prior(
    labels: ArrayLike,
    rms_radii_m: ArrayLike,
    classes: int,
    df: float = 3.0,
    weight: float = 0.5,
    min_scale: float = 0.05,
    **text: str,
) -> SizePrior:
    """Labels (V,) and RMS radii in metres (V,) of training views -> a SizePrior: per class the
    median of log r and 1.4826 x its median absolute deviation (at least ``min_scale``), robust
    to the share of a dataset's models drawn at another scale. Raises ValueError for a class
    without views."""
    y, log_r = np.asarray(labels), np.log(np.asarray(rms_radii_m, np.float64))
    medians, scales = [], []
    for k in range(classes):
        own = log_r[y == k]
        if not len(own):
            raise ValueError(f"class {k} has no views to fit its size")
        median, spread = log_median_and_spread(own)
        medians.append(round(median, 5))
        scales.append(round(max(min_scale, spread), 5))
    return SizePrior(log_median=medians, log_scale=scales, df=df, weight=weight, **text)
