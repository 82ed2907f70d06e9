"""How tall each category stands: a scene knows each object's top above the floor.

Pure numpy. A night stand and a dresser seen from the front are both a box's face to the
classifier, and a partial view's size (``itnet.size_prior``) tells them apart only weakly. On a
floor, the object's top is measured directly, and the categories differ in it: a night stand
stands about 0.66 m tall, a dresser 1.0 m. Per category, a Student-t over the log of the height
in metres (heavy-tailed, so an odd piece of furniture is not overruled), and::

    log p(c | cloud, height) = log p(c | cloud) + weight * log p(log h | c) + const

renormalised over the categories.

The table (``Category.height_m`` in ``itnet.model.categories``) is measured on ModelNet10's
training shapes, their units read as inches (as the
classifier's size prior reads them), the height their extent along ModelNet's up (+z):
``itnet fit heights --data ../shared/data/modelnet10`` measures it again.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.model.categories import MODELNET10
from itnet.size_prior import log_student_t

HEIGHTS_M: dict[str, tuple[float, float]] = {
    name: c.height_m for name, c in MODELNET10.items() if c.height_m is not None
}
"""Per category: (median height in metres, robust spread of its log: 1.4826 x MAD)."""

DF = 3.0  # Student-t degrees of freedom: heavy tails
WEIGHT = 1.0  # the height's log-likelihood is added times this (chosen on validation scenes)


def height_log_likelihood(categories: Sequence[str], height_m: float) -> NDArray[np.float64]:
    """log p(log h | c) (C,) for each of ``categories`` of an object whose top stands
    ``height_m`` metres above the floor, up to a constant they share; 0 for a category the
    table does not know (no evidence either way)."""
    known = [i for i, name in enumerate(categories) if name in HEIGHTS_M]
    out = np.zeros(len(categories))
    if known:
        medians, scales = zip(*(HEIGHTS_M[categories[i]] for i in known), strict=True)
        out[known] = log_student_t(float(np.log(max(height_m, 1e-3))), np.log(medians), scales, DF)
    return out


def with_height(
    categories: Sequence[str], probabilities: ArrayLike, height_m: float
) -> NDArray[np.float64]:
    """Probabilities (C,) of ``categories`` updated by the object's height (they sum to 1)."""
    p = np.maximum(np.asarray(probabilities, dtype=np.float64), 1e-12)
    logits = np.log(p) + WEIGHT * height_log_likelihood(categories, height_m)
    logits -= logits.max()
    q = np.exp(logits)
    return q / q.sum()
