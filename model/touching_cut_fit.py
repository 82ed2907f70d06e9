"""Fit the cut judge (``itnet.scene.touching``) on scenes of training shapes.

Development scenes (``itnet.model.scenes``, desks among them) of the pose models' training
shapes, half of them with their objects standing against each other (``touching``), are
rendered at 320x240 and segmented as served but without cuts; as many again are seen by a depth
camera's sensor model (``sensor``, default the Kinect v2), with things of no category among the
objects and the wall right behind them, since a real camera's noise, holes and flying pixels
change what a cut's strip holds. Each cluster's candidate cuts
(``cut_candidates``) are samples: ``two`` where the cluster holds two or more objects (each at
least 15% of its points) and the cut leaves at least 90% of each side's points to one object,
else ``one``. A network of one hidden layer is fitted to them (``fit_network``). Its threshold
is the lowest at which at most 0.5% of the clusters of ordinary validation scenes (every object
apart from the others; the usual ones and the camera's) would be cut::

    itnet fit touching-cut                  # writes the shipped file

Measuring it: ``benchmarks/bench_scene.py`` (``--touching``, ``--no-split-touching``).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator

from itnet.model.feature_network_fit import FeatureFitConfig, cached, fit_network, write_fitted
from itnet.model.scenes import FIT_SPLIT, WITH_DESKS, make_scene, split_shapes
from itnet.model.sensor import SENSORS
from itnet.scene.inputs import from_depth
from itnet.scene.segment import SegmentOptions, segment
from itnet.scene.touching import CLASSES, FILE, CutJudge, cut_candidates

MERGED_SHARE = 0.15  # an object with this share of a cluster's points is in it
CLEAN = 0.9  # a cut parts two objects where each side is this pure
MAX_CUT_SHARE = 0.005  # of ordinary validation clusters: the threshold's rule


def cut_samples(
    shapes: dict, scenes: int, seed: int, touching: bool, **kind: Any
) -> tuple[NDArray[np.float64], list[str]]:  # fmt: skip
    """``scenes`` scenes of ``shapes`` (``make_scene``'s ``kind`` beside ``touching``: a
    sensor, distractors, ...) -> every candidate cut's features (S, F) of every cluster the
    segmentation found, and its label: ``CLUSTER:LABEL`` (the cluster's running number in these
    samples, and ``one`` or ``two``)."""
    rng = np.random.default_rng(seed)
    features, labels = [], []
    cluster = 0
    for _ in range(scenes):
        scene = make_scene(shapes, rng, touching=touching, **{"categories": WITH_DESKS, **kind})
        given = from_depth(scene.depth, scene.intrinsics)
        found = segment(given.points, SegmentOptions(split_touching=False))
        if found.floor is None:
            continue
        for rows in found.objects:
            owner = scene.labels.ravel()[given.indices[rows]]
            count = np.bincount(owner, minlength=len(scene.objects) + 1)
            merged = int((count[1:] >= MERGED_SHARE * len(rows)).sum()) >= 2
            for cut in cut_candidates(given.points[rows], found.floor):
                side = cut.side(given.points[rows])
                pure = sum(np.bincount(owner[s], minlength=len(count)).max() for s in (side, ~side))
                two = merged and pure >= CLEAN * len(rows)
                features.append(cut.features)
                labels.append(f"{cluster}:{'two' if two else 'one'}")
            cluster += 1
    return np.array(features), labels


def sensor_kind(sensor: str) -> dict[str, Any]:
    """The scenes a camera's fitting samples come from: seen by ``sensor``, with things of no
    category among the objects and the wall right behind the farthest, as a real room is."""
    return {"sensor": sensor, "distractors": 2, "against_wall": True}


def fitting_kinds(sensor: str | None) -> list[tuple[bool, dict[str, Any]]]:
    """The kinds of scenes the judge is fitted on, in order (each ``seed`` + its place): objects
    touching and apart, and the same seen by ``sensor`` where given."""
    kinds: list[tuple[bool, dict[str, Any]]] = [(True, {}), (False, {})]
    if sensor is not None:
        kinds += [(True, sensor_kind(sensor)), (False, sensor_kind(sensor))]
    return kinds


def joined(parts: list[tuple[NDArray[np.float64], list[str]]]) -> tuple[NDArray, list[str]]:
    """Several ``cut_samples`` -> one, each part's clusters numbered apart (``P.CLUSTER:LABEL``)."""
    features = np.concatenate([x for x, _ in parts])
    return features, [f"{p}.{label}" for p, (_, labels) in enumerate(parts) for label in labels]


def cut_threshold(judge: CutJudge, features: NDArray, labels: list[str]) -> tuple[float, int]:
    """Ordinary scenes' candidate cuts (S, F) and labels (``cut_samples``) -> the lowest
    threshold at which at most MAX_CUT_SHARE of their one-object clusters would be cut, and how
    many such clusters there were."""
    chance = judge.probabilities(features)
    best: dict[str, float] = {}
    for p, label in zip(chance, labels):
        cluster, kind = label.split(":")
        if kind == "one":
            best[cluster] = max(best.get(cluster, 0.0), float(p))
    ordered = np.sort(np.array(list(best.values())))[::-1]
    allowed = int(MAX_CUT_SHARE * len(ordered))
    threshold = float(ordered[allowed]) + 1e-6 if len(ordered) > allowed else 0.5
    return min(max(threshold, 0.5), 1.0), len(ordered)


class TouchingCutFit(FeatureFitConfig):
    """How the cut judge is fitted: scenes of each kind (touching and apart) and the network."""

    scenes: int = Field(default=1500, ge=1, description="scenes of each kind")
    seed: int = Field(default=41, description="their seed")
    hidden: int = Field(default=32, ge=1, description="hidden units (chosen on validation scenes)")
    weight_decay: float = Field(default=1e-4, ge=0, description="chosen on validation")
    epochs: int = Field(default=1500, ge=1, description="chosen on validation")
    threshold_scenes: int = Field(
        default=300, ge=1, description="ordinary validation scenes the threshold is chosen on"
    )
    threshold_seed: int = Field(default=32, description="their seed")
    sensor: str | None = Field(
        default="kinect_v2",
        description="as many scenes again of each kind seen by this camera (with things of no "
        "category and a wall behind), for the fit and the threshold; none: only the usual "
        "scenes' structured-light noise",
    )
    out: Path = Field(default=FILE, description="the file written (default: the shipped one)")

    @field_validator("sensor")
    @classmethod
    def _known_sensor(cls, value: str | None) -> str | None:
        if value is None or value == "none":
            return None
        if value not in SENSORS:
            raise ValueError(f"unknown camera {value!r} (known: {', '.join(SENSORS)}, none)")
        return value


def fit_cut_judge(config: TouchingCutFit) -> CutJudge:
    """Fit the cut judge and its threshold on scenes of training shapes, write it to
    ``config.out`` and return it."""
    started = time.perf_counter()

    def fitting_samples() -> tuple[NDArray[np.float64], list[str]]:
        shapes = split_shapes(config.data, FIT_SPLIT, config.cache)
        return joined([cut_samples(shapes, config.scenes, config.seed + k, touching, **kind)
                       for k, (touching, kind) in enumerate(fitting_kinds(config.sensor))])  # fmt: skip

    def threshold_samples() -> tuple[NDArray[np.float64], list[str]]:
        shapes = split_shapes(config.data, "validation", config.cache)
        apart = [kind for touching, kind in fitting_kinds(config.sensor) if not touching]
        return joined([cut_samples(shapes, config.threshold_scenes, config.threshold_seed + k,
                                   touching=False, **kind) for k, kind in enumerate(apart)])  # fmt: skip

    features, labels = cached(config.samples, fitting_samples)
    kinds = [label.split(":")[1] for label in labels]
    network = fit_network(
        features, kinds, CLASSES, config.hidden, config.weight_decay, config.epochs
    )
    judge = CutJudge(network, 1.0, {})
    x, y = cached(config.threshold_samples, threshold_samples)
    threshold, clusters = cut_threshold(judge, x, y)
    fit = {
        "scenes": [{"split": FIT_SPLIT, "scenes": config.scenes, "seed": config.seed + k,
                    "touching": touching, **kind}
                   for k, (touching, kind) in enumerate(fitting_kinds(config.sensor))],
        "cuts": {c: kinds.count(c) for c in CLASSES},
        "network": {"hidden": config.hidden, "weight_decay": config.weight_decay,
                    "epochs": config.epochs},
        "threshold": {"most_cut": MAX_CUT_SHARE, "validation_scenes": config.threshold_scenes,
                      "seed": config.threshold_seed, "sensor": config.sensor,
                      "clusters": clusters},
        "command": "itnet fit touching-cut",
    }  # fmt: skip
    fitted = replace(judge, threshold=threshold, fit=fit)
    write_fitted(config.out, fitted, started)
    return fitted
