"""Fit the scene classifier (``itnet.scene.scene_classifier``) on scenes of training shapes.

Development scenes (``itnet.model.scenes``, desks among them) are made of ModelNet10's training
split: of the shapes the category classifiers left out of their training (their validation
carve-out), and of the others (on which the classifier is surer than it will be on new shapes;
the two sets together named the validation scenes' objects best), and more of the held-out
shapes with objects that may stand so near the camera that their lower parts lie below the
view (``make_scene(cut_off=True)``), rendered at 320x240 and segmented as served. Every
cluster matched to a scene object gives its features (``cluster_features``: the classifier's
log-probabilities as served, and the cluster's shape on the floor) and the object's category;
a network of one hidden layer is fitted to them (full batch, Adam, weight decay). Its
threshold (below it an answer is ``unsure``) is the lowest at which 95% of the validation
scenes' clusters above it are named right::

    itnet fit scene-classifier                     # writes the shipped file
    itnet fit scene-classifier --model-dir DIR --out FILE

The file names the classifier's graphs by their SHA-256, so it serves only them. Measuring it:
``benchmarks/bench_scene.py`` (``--no-scene-classifier``).
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator

from itnet.model.feature_network_fit import FeatureFitConfig, cached, fit_network, write_fitted
from itnet.model.scenes import (
    FIT_SPLIT,
    HELD_OUT_SPLIT,
    WITH_DESKS,
    make_scene,
    matched_objects,
    split_shapes,
)
from itnet.model.sensor import SENSORS
from itnet.pose.catalog import Catalog
from itnet.scene import scene_catalog
from itnet.scene.inputs import from_depth
from itnet.scene.pipeline import VIEWPOINT, shipped_catalog
from itnet.scene.posing import BadCloudError, classifier_probabilities
from itnet.scene.scene_classifier import (
    FILE,
    OTHER,
    SceneClassifier,
    classifier_graphs,
    cluster_features,
)
from itnet.scene.segment import segment

PROGRESS_EVERY = 500  # scenes between two progress lines
PRECISION = 0.95  # the threshold: the lowest at which this share of the answers above it is right


def scene_samples(
    shapes: dict, scenes: int, seed: int, catalog: Catalog, cut_off: bool = False,
    distractors: int = 0, sensors: tuple[str | None, ...] = (None,), no_one_object: bool = False,
    name: str = "scenes", on_top: float = 0.0,
) -> tuple[NDArray[np.float64], list[str]]:  # fmt: skip
    """``scenes`` scenes of ``shapes`` (``cut_off``: objects' lower parts may lie below the
    view; ``distractors``: up to this many things of no category among the objects;
    ``sensors``: each scene seen by one of these cameras, drawn at random (None: the scenes'
    structured-light noise; ``make_scene``); ``no_one_object``: a cluster half of whose points
    belong to no one object or thing (a piece of wall, two objects joined) counts as ``OTHER``;
    ``on_top``: the chance that an object carries things on its top, ``make_scene``'s)
    -> the features (S, F) of every cluster the segmentation found and matched to a scene
    object or thing, and those objects' categories (``OTHER`` for a thing) (S,). A line on
    stderr every ``PROGRESS_EVERY`` scenes, ``name`` first."""
    rng = np.random.default_rng(seed)
    features, labels = [], []
    started = time.perf_counter()
    for k in range(scenes):
        if k and k % PROGRESS_EVERY == 0:
            print(f"{name}: {k} of {scenes} scenes, {len(labels)} clusters, "
                  f"{time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)  # fmt: skip
        sensor = sensors[int(rng.integers(len(sensors)))] if len(sensors) > 1 else sensors[0]
        scene = make_scene(shapes, rng, categories=WITH_DESKS, cut_off=cut_off,
                           distractors=distractors, sensor=sensor, on_top=on_top)  # fmt: skip
        given = from_depth(scene.depth, scene.intrinsics)
        found = segment(given.points)
        if found.floor is None:
            continue
        returned = [given.indices[rows] for rows in found.objects]
        named = [o.category for o in scene.objects] + [OTHER] * len(scene.others)
        for i, label in sorted(
            cluster_labels(returned, scene.labels, named, no_one_object).items()
        ):
            points = given.points[found.objects[i]]
            try:  # the classifier's probabilities as served
                _, probabilities, _ = classifier_probabilities(catalog, points, found.up)
            except BadCloudError:
                continue
            log_p = np.log(np.maximum(probabilities, 1e-12))
            features.append(cluster_features(points, log_p, found.floor, VIEWPOINT))
            labels.append(label)
    return np.array(features), labels


def cluster_labels(
    returned: list[NDArray[np.int64]], labels: NDArray[np.int64], named: list[str],
    no_one_object: bool = False,
) -> dict[int, str]:  # fmt: skip
    """Clusters' pixel indices (each (K,), flat) against a scene's ``labels`` (H, W) (0: floor
    or wall, k: the thing ``named[k - 1]``) -> the label each cluster is learned as, by its
    index: the name of the object or thing it matches (``matched_objects``); with
    ``no_one_object``, ``OTHER`` for one that matches none and of whose pixels no object or
    thing holds half (a piece of wall, two objects joined). A cluster mostly of one object that
    matches it poorly (a piece of it) is left out."""
    out = {i: named[k - 1] for i, k in matched_objects(returned, labels, len(named))}
    if no_one_object:
        flat = labels.ravel()
        for i, pixels in enumerate(returned):
            most = np.bincount(flat[pixels], minlength=len(named) + 1)[1:].max(initial=0)
            if i not in out and 2 * most < len(pixels):
                out[i] = OTHER
    return out


def precision_threshold(
    probabilities: NDArray, right: NDArray, precision: float = PRECISION
) -> float:
    """Top probabilities (S,) and whether each answer was right (S,) -> the lowest threshold at
    which at least ``precision`` of the answers at or above it are right (1.0 where none)."""
    order = np.argsort(-probabilities, kind="stable")
    shares = np.cumsum(right[order]) / np.arange(1, len(order) + 1)
    ok = np.flatnonzero(shares >= precision)
    return float(probabilities[order][ok[-1]]) if len(ok) else 1.0


def camera_names(sensors: str) -> tuple[str, ...]:
    """'default,kinect_v2,...' -> the names, each 'default' (the scenes' own noise) or one of
    ``SENSORS``; ValueError for none or another."""
    names = tuple(n.strip() for n in sensors.split(",") if n.strip())
    unknown = set(names) - {"default", *SENSORS}
    if not names or unknown:
        raise ValueError(f"unknown {sorted(unknown)} (known: default, {', '.join(SENSORS)})")
    return names


class SceneClassifierFit(FeatureFitConfig):
    """How the scene classifier is fitted: the scenes its samples come from and the network."""

    scenes: int = Field(default=4000, ge=1, description="scenes of held-out shapes")
    seed: int = Field(default=21, description="their seed")
    train_scenes: int = Field(default=3000, ge=0, description="scenes of the other shapes")
    train_seed: int = Field(default=22, description="their seed")
    train_shapes: int = Field(default=150, ge=1, description="of the others, a category")
    cut_off_scenes: int = Field(
        default=2000,
        ge=0,
        description="scenes of held-out shapes whose objects' lower parts may lie below the view",
    )
    cut_off_seed: int = Field(default=23, description="their seed")
    distractors: int = Field(
        default=1,
        ge=0,
        description="up to this many things of no category in each scene of the first two "
        "kinds (its class OTHER; 0: none, no such class)",
    )
    sensors: str = Field(
        default="default,kinect_v1,kinect_v2,realsense_d435",
        description="the cameras the scenes of the first two kinds are seen by, one drawn per "
        "scene (default: the scenes' structured-light noise; model/sensor.py's presets)",
    )
    no_one_object: bool = Field(
        default=False,
        description="clusters half of whose points belong to no one object or thing (a piece "
        "of wall, two objects joined) join the class OTHER, in every kind of scene",
    )
    on_top: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="the chance that an object in the scenes of the first two kinds carries "
        "things on its top (a lamp, books, a vase, a plant, a mirror), learned as part of it",
    )
    hidden: int = Field(default=64, ge=1, description="hidden units (chosen on validation scenes)")

    @field_validator("sensors")
    @classmethod
    def _known_cameras(cls, sensors: str) -> str:
        camera_names(sensors)
        return sensors

    def cameras(self) -> tuple[str | None, ...]:
        """``sensors`` as ``make_scene``'s ``sensor`` values (None: the default)."""
        return tuple(None if n == "default" else n for n in camera_names(self.sensors))

    weight_decay: float = Field(default=1e-3, ge=0, description="chosen on validation")
    epochs: int = Field(default=1000, ge=1, description="chosen on validation")
    threshold_scenes: int = Field(
        default=300, ge=1, description="validation scenes the threshold is chosen on"
    )
    threshold_seed: int = Field(default=5, description="their seed")
    out: Path = Field(default=FILE, description="the file written (default: the shipped one)")
    model_dir: Path | None = Field(
        default=None, description="the models whose classifier it names with (default: shipped)"
    )


def fit_scene_classifier(config: SceneClassifierFit) -> SceneClassifier:
    """Fit the scene classifier and its threshold, write it to ``config.out`` and return it."""
    catalog = shipped_catalog() if config.model_dir is None else scene_catalog(config.model_dir)
    assert catalog.classifier is not None
    started = time.perf_counter()

    def fitting_samples() -> tuple[NDArray[np.float64], list[str]]:
        held_out = split_shapes(config.data, HELD_OUT_SPLIT, config.cache)
        trained = split_shapes(config.data, FIT_SPLIT, config.cache, limit=config.train_shapes)
        mixed = config.no_one_object
        x1, y1 = scene_samples(held_out, config.scenes, config.seed, catalog,
                               distractors=config.distractors, sensors=config.cameras(),
                               no_one_object=mixed, name="held-out scenes",
                               on_top=config.on_top)  # fmt: skip
        x2, y2 = scene_samples(trained, config.train_scenes, config.train_seed, catalog,
                               distractors=config.distractors, sensors=config.cameras(),
                               no_one_object=mixed, name="training scenes",
                               on_top=config.on_top)  # fmt: skip
        x3, y3 = scene_samples(held_out, config.cut_off_scenes, config.cut_off_seed, catalog, True,
                               no_one_object=mixed, name="cut-off scenes")  # fmt: skip
        return np.concatenate([x1, x2, x3]), y1 + y2 + y3

    def threshold_samples() -> tuple[NDArray[np.float64], list[str]]:
        shapes = split_shapes(config.data, "validation", config.cache)
        return scene_samples(shapes, config.threshold_scenes, config.threshold_seed, catalog,
                             name="validation scenes")  # fmt: skip

    features, labels = cached(config.samples, fitting_samples)
    classes = tuple(sorted(set(labels)))
    network = fit_network(
        features, labels, classes, config.hidden, config.weight_decay, config.epochs
    )
    fitted = SceneClassifier(classes, tuple(catalog.classifier.card.classes),
                             classifier_graphs(catalog.classifier), network, threshold=1.0,
                             fit={})  # fmt: skip
    x, y = cached(config.threshold_samples, threshold_samples)
    probabilities = fitted.probabilities(x)
    if OTHER in classes:  # the categories' shares of the rest, as the scene names by them
        probabilities = np.delete(probabilities, classes.index(OTHER), axis=1)
        probabilities /= np.maximum(probabilities.sum(1, keepdims=True), 1e-300)
    named = np.array([c for c in classes if c != OTHER])[probabilities.argmax(1)]
    right = named == np.array(y)
    threshold = precision_threshold(probabilities.max(1), right)
    fit = {
        "scenes": {HELD_OUT_SPLIT: [config.scenes, config.seed],
                   FIT_SPLIT: [config.train_scenes, config.train_seed, config.train_shapes],
                   "cut_off": [config.cut_off_scenes, config.cut_off_seed],
                   "distractors": config.distractors, "sensors": config.sensors,
                   "no_one_object": config.no_one_object,
                   **({"on_top": config.on_top} if config.on_top else {})},
        "clusters": {c: labels.count(c) for c in classes},
        "network": {"hidden": config.hidden, "weight_decay": config.weight_decay,
                    "epochs": config.epochs},
        "threshold": {"precision": PRECISION, "validation_scenes": config.threshold_scenes,
                      "seed": config.threshold_seed, "clusters": len(y),
                      "named_right": round(float(right.mean()), 4)},
        "command": "itnet fit scene-classifier",
    }  # fmt: skip
    fitted = replace(fitted, threshold=threshold, fit=fit)
    write_fitted(config.out, fitted, started)
    return fitted
