"""The one place where scenes call the pose machinery: load the models and the classifier,
classify a cluster (``model: "auto"``, with up and the unit known), and run its category's
anytime pipeline with up and the viewpoint given, within a share of the scene's budget.

Everything a scene needs of the pose side goes through a ``Catalog`` and ``pose_object``: the
classification restricted to the scene's categories, then the one pose pipeline
(``Catalog.start``, as every path) by a request with up, the viewpoint, the points each run sees
and no schedule.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from itnet.columns import percentiles
from itnet.planes import Plane
from itnet.pose.catalog import Catalog
from itnet.pose.errors import BadCloudError, BudgetTooSmallError
from itnet.pose.recognition import classify, pose_model_for
from itnet.pose.reply import pose_fields
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import (
    LoadedModel,
    ModelLoadError,
    default_model_dir,
)
from itnet.scene.height_prior import with_height
from itnet.scene.scene_classifier import OTHER, SceneClassifier, cluster_features
from itnet.scene.unknown import unknown_reason

SCENE_UNITS = "m"  # scene clouds are in metres: the classifier's size prior counts
# A scene's object is posed by at least this many fused runs, their starts turned about up (a
# model whose card recommends fewer, the dresser's, gets this many; the others keep their own).
# Four is what a boxy dresser seen from the front needs (150 validation scenes: 30 of 37 right,
# 27 with one run) while leaving the scene's other objects their time.
SCENE_LEAST_RUNS = 4
# The most points each of a scene object's runs sees (the models' cards say 256, what they
# were trained on). A depth camera's object is noisy enough that half the points pose it as
# well, in about half the time a step (150 validation scenes, paired against 256: +2.7 +- 1.3 /
# +0.0 +- 1.5 points at 320x240 / 640x480; docs/scenes.md, "Posing").
SCENE_RUN_POINTS = 128
# The pose model of a category's objects whose base lies below the view, where the models have
# one: ``<category>_base_hidden`` (trained on such views: ``itnet train --base-hidden``).
BASE_HIDDEN_SUFFIX = "_base_hidden"


def scene_catalog(model_dir: Path | None = None, threads: int = 2) -> Catalog:
    """Every model of a folder (default: the shipped ones) as the pose pipeline serves them.
    Raises ModelLoadError, also where the folder has no category classifier (scenes classify
    every object)."""
    folder = model_dir or default_model_dir()
    catalog = Catalog.load(folder, threads)
    if catalog.classifier is None:
        raise ModelLoadError(f"{folder}: no category classifier (scenes need classifier.onnx)")
    return catalog


@dataclass
class ObjectPose:
    """One cluster's category (None: unknown) and, where its category has a pose model and the
    budget held a run, its pose: ``result`` is the anytime run's reply
    (``T_canonical_from_input``, both quaternions, iterations, ...) without the recognition's
    fields; ``pose`` (4, 4)."""

    category: str | None  # None: unknown (``unknown`` says why)
    probability: float
    candidates: list[dict[str, Any]]
    unsure: bool
    pose: NDArray[np.float64] | None = None
    result: dict[str, Any] | None = None
    no_pose: str | None = None  # why there is no pose: 'no_pose_model', 'budget' or 'unknown'
    named_by: str = "classifier"  # or 'scene_classifier': what named the category
    unknown: str | None = None  # 'not_ours', 'unsure' or 'too_large' (``itnet.scene.unknown``)
    # the scene classifier's probability that it is none of the categories (``OTHER``); the
    # categories' probabilities are shares of the rest
    other: float = 0.0


class NoClassifierError(RuntimeError):
    """The models' folder has no category classifier: scenes need one."""


def pose_object(
    catalog: Catalog,
    points: NDArray,
    up: NDArray,
    viewpoint: NDArray,
    budget_ms: float,
    started: float | None = None,
    min_run_ms: float = 2.0,
    categories: frozenset[str] | None = None,
    floor: Plane | None = None,
    scene_classifier: SceneClassifier | None = None,
    base_hidden: bool = False,
    base_hidden_models: bool = True,
    unknown: bool = True,
) -> ObjectPose:
    """A cluster (K, 3) in metres, its up (3,, unit) and the sensor's position (3,) -> its
    ObjectPose, the classification (``scene_category``) and the run within ``budget_ms`` from
    ``started`` (``time.perf_counter()``; default now). ``categories``: the ones the object may
    be (default: any); ``floor``: the plane it stands on, whose height it is measured from;
    ``scene_classifier``: the one to name it by (see ``scene_category``); ``base_hidden``:
    whether the object's base lies below the view (where ``base_hidden_models`` is on and its
    category has a model for such views, ``BASE_HIDDEN_SUFFIX``, that model poses it);
    ``unknown``: a cluster that no category fits is unknown (``itnet.scene.unknown``: category
    None, no pose). No run where less than ``min_run_ms`` is left after the classification.
    Raises BadCloudError (too few points, degenerate)."""
    started = time.perf_counter() if started is None else started
    seen = scene_category(catalog, points, up, viewpoint, started + budget_ms / 2e3, categories,
                          floor, scene_classifier)  # fmt: skip
    named = seen.category
    assert named is not None  # scene_category names one
    if unknown:
        top = None if floor is None else top_height(points, floor)
        seen.unknown = unknown_reason(named, seen.probability, points, up, seen.other, top)
        if seen.unknown is not None:
            seen.category, seen.no_pose = None, "unknown"
            return seen
    model = catalog.models.get(named + BASE_HIDDEN_SUFFIX) if base_hidden_models else None
    if model is None or model.card.category != named or not base_hidden:
        model = None  # the category's own
    return posed_as(catalog, seen, points, up, viewpoint, budget_ms, started, min_run_ms, model)


def scene_category(
    catalog: Catalog,
    points: NDArray,
    up: NDArray,
    viewpoint: NDArray,
    deadline: float | None = None,
    categories: frozenset[str] | None = None,
    floor: Plane | None = None,
    scene_classifier: SceneClassifier | None = None,
) -> ObjectPose:
    """A cluster (K, 3) in metres, its up (3,) and the sensor's position (3,) -> its category,
    probability, top-3 candidates and whether it is unsure (an ObjectPose without a pose).

    The classifier's probabilities (``model: "auto"`` with up and metres; a second opinion
    where unsure that ends by ``deadline``, ``time.perf_counter()`` seconds), then, on a
    ``floor``: by ``scene_classifier`` (its own threshold) where one is given and names some of
    ``categories``, else weighed by the object's height (``height_prior``). Restricted to
    ``categories`` (renormalised; default: any). Raises BadCloudError."""
    names, probabilities, threshold = classifier_probabilities(catalog, points, up, deadline)
    named_by, other = "classifier", 0.0
    if (
        floor is not None
        and scene_classifier is not None
        and (categories is None or categories & set(scene_classifier.classes))
    ):
        features = cluster_features(points, np.log(np.maximum(probabilities, 1e-12)), floor,
                                    viewpoint)  # fmt: skip
        names = list(scene_classifier.classes)
        probabilities = scene_classifier.probabilities(features)
        threshold = scene_classifier.threshold
        named_by = "scene_classifier"
        if OTHER in names:  # none of the categories: apart, the categories share the rest
            other = float(probabilities[names.index(OTHER)])
            names, probabilities = (
                [n for n in names if n != OTHER],
                np.delete(probabilities, names.index(OTHER)),
            )
    elif floor is not None:
        probabilities = with_height(names, probabilities, top_height(points, floor))
    kept = [i for i, name in enumerate(names) if categories is None or name in categories]
    if not kept:
        raise BadCloudError(f"none of the categories {sorted(categories or ())} is known")
    names = [names[i] for i in kept]
    probabilities = probabilities[kept] / max(float(probabilities[kept].sum()), 1e-300)
    order = np.argsort(-probabilities, kind="stable")
    top = [
        {"category": names[i], "probability": round(float(probabilities[i]), 6)} for i in order[:3]
    ]
    probability = round(float(probabilities[order[0]]), 6)
    return ObjectPose(names[order[0]], probability, top, probability < threshold,
                      named_by=named_by, other=round(other, 6))  # fmt: skip


def classifier_probabilities(
    catalog: Catalog, points: NDArray, up: NDArray, deadline: float | None = None
) -> tuple[list[str], NDArray[np.float64], float]:
    """A cluster (K, 3) in metres and its up (3,) -> the classifier's classes, its
    probabilities (C,) of each (``model: "auto"`` with up and the unit: the upright classifier
    and the size prior join; a second opinion where unsure that ends by ``deadline``) and its
    threshold. Raises NoClassifierError, BadCloudError."""
    if catalog.classifier is None:
        raise NoClassifierError("scenes need the category classifier, and none is loaded")
    classes = list(catalog.classifier.card.classes)
    recognition = classify(catalog.classifier, points, top=len(classes), limits=catalog.limits,
                           units=SCENE_UNITS, up=up, deadline=deadline)  # fmt: skip
    given = {c.category: c.probability for c in recognition.candidates}
    probabilities = np.array([given.get(c, 0.0) for c in classes], dtype=np.float64)
    return classes, probabilities, recognition.threshold


def top_height(points: NDArray, floor: Plane) -> float:
    """How high an object's top stands above ``floor``: the 98th percentile of its points' (K,
    3) heights (against noise), in the points' unit."""
    return float(percentiles(floor.distance(points), [98])[0])


def posed_as(
    catalog: Catalog,
    seen: ObjectPose,
    points: NDArray,
    up: NDArray,
    viewpoint: NDArray,
    budget_ms: float,
    started: float,
    min_run_ms: float = 2.0,
    model: LoadedModel | None = None,
) -> ObjectPose:
    """``seen`` (its category) with its pose: the category's anytime pipeline (or ``model``'s)
    started by ``catalog.start`` on the cluster (K, 3) with up and the viewpoint (at least
    SCENE_LEAST_RUNS fused runs, or one where the budget holds no more; each run on at most
    SCENE_RUN_POINTS points; no schedule: the cards' schedules were measured on views of single
    objects), within ``budget_ms`` from ``started``; ``no_pose`` says why not where it has none
    (no model for the category, or the budget)."""
    model = model or (
        None if seen.category is None else pose_model_for(seen.category, catalog.models)
    )
    if model is None:
        seen.no_pose = "no_pose_model"
        return seen
    left_ms = budget_ms - (time.perf_counter() - started) * 1e3
    if left_ms < min_run_ms:
        seen.no_pose = "budget"
        return seen
    runs = SCENE_LEAST_RUNS if model.card.recommended_ensemble < SCENE_LEAST_RUNS else None
    run = None
    for ensemble in (runs, 1):  # a share too small for the fused runs gets one run
        request = PoseRequest(model=model.card.name, budget_ms=float(budget_ms),
                              up=[float(v) for v in up], viewpoint=[float(v) for v in viewpoint],
                              ensemble=ensemble, points_per_run=SCENE_RUN_POINTS,
                              schedule=False, strip=False)  # fmt: skip
        try:
            run = catalog.start(points, request, started)
            break
        except BudgetTooSmallError:
            continue
    if run is None:
        seen.no_pose = "budget"
        return seen
    run.run_to_end()
    if run.iteration == 0:  # the start is no pose
        seen.no_pose = "budget"
        return seen
    seen.result = run.result()
    seen.pose = run.last.pose
    return seen


def with_pose(result: dict[str, Any], pose: NDArray[np.float64]) -> dict[str, Any]:
    """A run's reply with its pose fields (matrix, quaternions, translation) replaced by
    ``pose`` (4, 4)."""
    return {**result, **pose_fields(pose)}


__all__ = [
    "BadCloudError",
    "ModelLoadError",
    "NoClassifierError",
    "ObjectPose",
    "classifier_probabilities",
    "pose_object",
    "scene_catalog",
    "scene_category",
    "top_height",
    "with_pose",
]
