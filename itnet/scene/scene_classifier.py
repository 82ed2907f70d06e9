"""A scene object's category from everything the scene tells: the scene classifier.

The category classifier sees a cluster normalised, as it sees any cloud: from the front a
dresser is a flat face, a table's top seen at the horizon a desk's. A scene says more: how tall
the object stands on the floor, how wide and deep it reaches seen from the camera, where along
its height its points lie. The scene classifier is a small network (one hidden layer) over the
classifier's log-probabilities (as ``model: "auto"`` serves them, upright classifier and size
prior included) and those measures of the cluster (``cluster_features``), fitted on clusters
that the segmentation found in scenes of shapes the classifier never saw in training (its
validation carve-out of ModelNet10's training split): ``itnet fit scene-classifier``.

It names the categories of its fitting scenes: furniture that stands on the floor. The monitor,
which stands on a desk, is not among them; a request restricted to categories it does not name
is classified without it (by the classifier with the object's height, ``height_prior``). Where
its fitting scenes held things of no category (ottomans, bins, lamps, plants, cabinets:
``model.distractors``), it also has the class ``OTHER``: a cluster it finds likelier to be such
a thing than any category is answered unknown (``not_ours``).

The file (``scene_classifier.json``) names the classifier's graphs by their SHA-256: another
model folder, or a classifier trained again, gets no scene classifier until it is refitted.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.columns import percentiles
from itnet.graph_digest import graph_digest
from itnet.planes import Plane
from itnet.pose.runtime import LoadedClassifier
from itnet.scene.feature_network import FeatureNetwork

FILE = Path(__file__).with_name("scene_classifier.json")
OTHER = "other"  # the class of things that are none of the categories
MIN_LOG_PROBABILITY = float(np.log(1e-6))  # the classifier's log-probabilities floored here
HEIGHT_BINS = 6  # the share of the points in each sixth of the object's height
MIN_EXTENT_M = 0.02


def cluster_features(
    points: NDArray, log_probabilities: ArrayLike, floor: Plane, viewpoint: NDArray
) -> NDArray[np.float64]:
    """A cluster (K, 3) standing on ``floor`` (its normal up), the classifier's
    log-probabilities (C,) of it and the camera's position (3,) -> its features (C + 21,):
    the log-probabilities floored at log 1e-6; the log of its top's height (98th percentile);
    the share of its points in each sixth of that height; the mean height over the top; the
    logs of its width (across the camera's view, 5th-95th percentile) and depth (along it), of
    its footprint's two principal spreads, and of its distance along the floor; its 3-D
    spreads' ratios (flatness, elongation); the depth and width of its bottom, middle and top
    thirds over its width, as logs."""
    p = np.asarray(points, dtype=np.float64)
    up = floor.normal
    heights = floor.distance(p)
    top = max(float(percentiles(heights, [98])[0]), 0.05)
    level = np.clip(heights / top, 0.0, 0.999)
    shares = np.bincount((level * HEIGHT_BINS).astype(int), minlength=HEIGHT_BINS) / len(p)
    toward = np.asarray(viewpoint, dtype=np.float64) - p.mean(0)
    toward -= (toward @ up) * up
    distance = max(float(np.linalg.norm(toward)), 1e-3)
    toward /= distance
    across = np.cross(up, toward)
    a, b = p @ across, p @ toward
    width = max(_spread(a, 5), MIN_EXTENT_M)
    depth = max(_spread(b, 5), MIN_EXTENT_M)
    footprint = np.sort(np.linalg.eigvalsh(np.cov(np.stack([a, b]))))[::-1]
    body = np.sort(np.linalg.eigvalsh(np.cov(p.T)))[::-1]
    thirds = []
    for lo, hi in ((0.0, 1 / 3), (1 / 3, 2 / 3), (2 / 3, 1.0)):
        inside = (level >= lo) & (level < hi)
        reach_b = _spread(b[inside], 10) if inside.sum() >= 5 else 0.0
        reach_a = _spread(a[inside], 10) if inside.sum() >= 5 else 0.0
        thirds += [np.log(max(reach_b, 0.01) / max(width, 0.05)),
                   np.log(max(reach_a, 0.01) / max(width, 0.05))]  # fmt: skip
    lp = np.maximum(np.asarray(log_probabilities, dtype=np.float64), MIN_LOG_PROBABILITY)
    shape = [
        np.log(top), *shares, np.log(width), np.log(depth),
        0.5 * np.log(max(footprint[0], 1e-6)), 0.5 * np.log(max(footprint[1], 1e-6)),
        body[2] / max(body[0], 1e-12), body[1] / max(body[0], 1e-12), np.log(distance),
        *thirds, float(np.mean(heights)) / top,
    ]  # fmt: skip
    return np.concatenate([lp, np.asarray(shape, dtype=np.float64)])


def _spread(values: NDArray, percent: float) -> float:
    """How far ``values`` (K,) reach between their ``percent``-th and (100 - percent)-th
    percentiles."""
    lo, hi = percentiles(values, [percent, 100 - percent])
    return float(hi - lo)


@dataclass(frozen=True)
class SceneClassifier:
    """features (F,) -> probabilities over ``classes`` by ``network``. ``inputs``: the
    classifier's classes, in the order of its log-probabilities in the features; ``graphs``: the
    SHA-256 of the classifier's graph and of its upright classifier's ('' for none);
    ``threshold``: below it the answer is unsure; ``fit``: how it was fitted and measured."""

    classes: tuple[str, ...]
    inputs: tuple[str, ...]
    graphs: tuple[str, str]
    network: FeatureNetwork
    threshold: float
    fit: dict[str, Any]

    def probabilities(self, features: ArrayLike) -> NDArray[np.float64]:
        """features (..., F) -> probabilities (..., C) over ``classes``."""
        return self.network.probabilities(features)

    def serves(self, classifier: LoadedClassifier) -> bool:
        """Whether it was fitted on this classifier's graphs (and its classes)."""
        return (
            tuple(classifier.card.classes) == self.inputs
            and classifier_graphs(classifier) == self.graphs
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "classes": list(self.classes),
            "inputs": list(self.inputs),
            "graphs": {"classifier": self.graphs[0], "upright": self.graphs[1]},
            "threshold": self.threshold,
            **self.network.to_dict(),
            "fit": self.fit,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SceneClassifier:
        return cls(tuple(d["classes"]), tuple(d["inputs"]),
                   (d["graphs"]["classifier"], d["graphs"]["upright"]), FeatureNetwork.from_dict(d),
                   threshold=float(d["threshold"]), fit=d.get("fit", {}))  # fmt: skip


def classifier_graphs(classifier: LoadedClassifier) -> tuple[str, str]:
    """The SHA-256 of a loaded classifier's graph and of its upright classifier's ('' without)."""
    upright = classifier.upright
    return graph_digest(classifier.path), "" if upright is None else graph_digest(upright.path)


@lru_cache(maxsize=4)
def load_scene_classifier(path: Path = FILE) -> SceneClassifier | None:
    """The scene classifier at ``path`` (None where there is no file)."""
    if not path.exists():
        return None
    return SceneClassifier.from_dict(json.loads(path.read_text()))


__all__ = [
    "FILE",
    "OTHER",
    "SceneClassifier",
    "classifier_graphs",
    "cluster_features",
    "load_scene_classifier",
]
