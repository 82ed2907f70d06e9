"""A cluster too large for any category, split where the recognition finds two objects in it.

A table with its chairs, a bed with a night stand beside it, a dresser against a chest: objects
standing against each other make one cluster, and where the cut judge (``touching``) did not part
it, it is larger than any real piece of the category it is named (``unknown``: too large). A cluster
named with little confidence is not tried: it is more often a thing of no category, or one seen
poorly (its name less sure where the budget cut the classifier's second opinion short), than two
objects. Each of the cut judge's candidate planes through such a cluster (its likeliest ``TRIED``
first) parts it in two, and each part is classified as the scene names objects
(``posing.scene_category``, on at most ``PART_POINTS`` of its points); the cut is made where both
parts are objects some category fits (``unknown.unknown_reason`` finds nothing against them), the
one whose less certain part is the most certain. Where no cut gives two such parts the cluster stays
one, unknown.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from itnet.planes import Plane
from itnet.pose.catalog import Catalog
from itnet.pose.errors import BadCloudError
from itnet.scene.posing import scene_category, top_height
from itnet.scene.scene_classifier import SceneClassifier
from itnet.scene.touching import CutJudge, cut_candidates
from itnet.scene.unknown import unknown_reason

TRIED = 3  # candidate cuts classified, likeliest first by the cut judge
PART_POINTS = 1024
MIN_PART_POINTS = 200  # a part with fewer points is no object


@dataclass(frozen=True)
class Namer:
    """What names a scene's clusters: the models, the scene classifier, the categories allowed,
    the floor and the camera."""

    catalog: Catalog
    scene_classifier: SceneClassifier | None
    categories: frozenset[str] | None
    floor: Plane
    viewpoint: NDArray[np.float64]

    def confidence(self, points: NDArray, deadline: float) -> float | None:
        """How sure the scene is of a cluster's (K, 3) category: its probability, or None where
        it is unknown (``unknown_reason``) or cannot be classified."""
        sample = points[:: max(1, len(points) // PART_POINTS)]
        try:
            seen = scene_category(self.catalog, sample, self.floor.normal, self.viewpoint,
                                  deadline, self.categories, self.floor,
                                  self.scene_classifier)  # fmt: skip
        except BadCloudError:
            return None
        assert seen.category is not None
        top = top_height(sample, self.floor)
        if unknown_reason(seen.category, seen.probability, sample, self.floor.normal, seen.other,
                          top):  # fmt: skip
            return None
        return seen.probability


def named_parts(
    points: NDArray, namer: Namer, judge: CutJudge | None, deadline: float
) -> list[NDArray[np.int64]]:
    """A cluster (K, 3) too large for its category -> the indices (into ``points``) of the
    objects the recognition finds in it: two parts, or the whole where no cut parts it into two
    objects some category fits, or where ``deadline`` (``time.perf_counter()``) passes first."""
    whole = [np.arange(len(points))]
    if len(points) < 2 * MIN_PART_POINTS:
        return whole
    cuts = cut_candidates(points, namer.floor, namer.viewpoint)
    if judge is not None and cuts:
        chance = np.nan_to_num(judge.probabilities(np.stack([c.features for c in cuts])), nan=0.0)
        cuts = [cuts[k] for k in np.argsort(-chance, kind="stable")]
    best, best_side = 0.0, None
    for cut in cuts[:TRIED]:
        if time.perf_counter() > deadline:
            break
        side = cut.side(points)
        if min(side.sum(), (~side).sum()) < MIN_PART_POINTS:
            continue
        first, second = (namer.confidence(points[part], deadline) for part in (side, ~side))
        if first is not None and second is not None and min(first, second) > best:
            best, best_side = min(first, second), side
    if best_side is None:
        return whole
    return [np.flatnonzero(best_side), np.flatnonzero(~best_side)]


__all__ = ["MIN_PART_POINTS", "PART_POINTS", "TRIED", "Namer", "named_parts"]
