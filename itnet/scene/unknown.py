"""An object that no category fits: answered as unknown, with its box and points, not dropped.

A scene holds things that are none of the classifier's categories (a lamp, an ottoman, a
plant, a box) and clusters that are two or more objects standing against each other (a table
with its chairs, a bed with a night stand). Either is named by some category all the same;
it is answered as unknown (``category: null``, no pose) where

* ``unsure``: the probability of the category named is below ``UNKNOWN_BELOW``, or
* ``not_ours``: the scene classifier finds it likelier a thing of none of the categories (its
  class ``OTHER``, fitted on scenes with ottomans, bins, lamps, plants and cabinets) than any
  category, or
* ``too_large``: the cluster is larger than any real piece of the category named: its
  bounding radius (half the diagonal of its box along up and its widest horizontal
  direction, from the 2nd to the 98th percentile of its points) exceeds ``TOO_LARGE`` times
  the category's largest real radius (``itnet.model.categories.REAL_RADIUS_M``). A partial
  view of one object is never larger than the object, so the margin is for noise and for a
  strip of floor or wall the cluster keeps. Or, on a floor, its top stands higher than
  ``TOO_TALL_M``: no category that stands on a floor is that tall (the tallest, a bed's
  headboard or a dresser with what stands on it, reach about 1.6 m), so such a cluster is
  something else (a wardrobe, a curtain, a door) or holds one.

Pure numpy.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from itnet.columns import column_mean, percentiles
from itnet.model.categories import REAL_RADIUS_M

# a category named with less probability than this is unknown (chosen on validation scenes:
# docs/scenes.md, "Unknown objects")
UNKNOWN_BELOW = 0.5
TOO_LARGE = 1.3  # times the category's largest real radius
TOO_TALL_M = 2.0  # a top higher above the floor than this: none of the categories


def cluster_radius(points: NDArray, up: NDArray) -> float:
    """Half the diagonal of a cluster's (K, 3) robust box along ``up`` (3,, unit) and its
    widest horizontal direction, metres (2nd to 98th percentile along each axis)."""
    p = np.asarray(points, dtype=np.float64)
    heights = p @ up
    flat = p - np.outer(heights, up)
    flat = flat - column_mean(flat)
    _, _, vt = np.linalg.svd(flat[:: max(1, len(flat) // 2000)], full_matrices=False)
    axes = np.stack([vt[0], np.cross(up, vt[0])])
    spans = [np.subtract(*percentiles(flat @ a, [98, 2])) for a in axes]
    spans.append(float(np.subtract(*percentiles(heights, [98, 2]))))
    return 0.5 * float(np.linalg.norm(spans))


def unknown_reason(
    category: str, probability: float, points: NDArray, up: NDArray, other: float = 0.0,
    top_m: float | None = None,
) -> str | None:  # fmt: skip
    """Why a cluster (K, 3) in metres named ``category`` with ``probability`` (among the
    categories), and none of them with ``other`` (the scene classifier's ``OTHER``, as a share
    of all its classes), its top ``top_m`` above the floor where it stands on one, is unknown
    ('not_ours', 'unsure', 'too_large'), or None where the category stands (a category without
    real sizes, a user's, is never too large)."""
    if other > probability * (1.0 - other):  # OTHER is likelier than the category named
        return "not_ours"
    if probability < UNKNOWN_BELOW:
        return "unsure"
    sizes = REAL_RADIUS_M.get(category)
    if sizes is None:
        return None
    too_tall = top_m is not None and top_m > TOO_TALL_M
    if too_tall or cluster_radius(points, up) > TOO_LARGE * sizes[1]:
        return "too_large"
    return None


__all__ = ["TOO_LARGE", "TOO_TALL_M", "UNKNOWN_BELOW", "cluster_radius", "unknown_reason"]
