"""``model: "auto"``: classify the cloud, then run the winning category's pose model.

One place for the logic: every path reaches it through ``itnet.pose.catalog.Catalog.start``
(HTTP, the WebSocket, ``itnet pose --model auto``, alignment, batch, scenes); ``itnet classify``
calls ``classify`` directly.

* The classifier (an IT-Net canonicaliser + PointNet classifier, one ONNX graph) sees the cloud
  normalised as the pose models see it (``itnet.preprocess``), capped at its card's point count.
* Its time counts against the request's budget: the pose run's clock starts when the request
  arrived, before the classification.
* The winning category's pose model is the loaded model named after it, else any loaded model
  whose card has that category. None loaded: a 422 (``kind: no_pose_model``) that names the
  category, its probability, the candidates and the loaded models.
* A known unit: a request that says its cloud's unit (``units``: m, cm, mm, in, ft) lets the
  cloud's size count as well as its form, where the classifier's card has a size prior
  (``itnet.size_prior``): a night stand and a dresser look alike normalised, not in metres.
* Unsure: when the top probability is below the card's ``threshold`` (chosen on validation views,
  see docs/classification.md), the pose model still runs, and the reply says ``unsure: true``
  beside the candidates, so a client can decide.
* Which way is up: a request that says it (``up``) is also classified by the upright classifier
  where one is loaded (``LoadedClassifier.upright``, a card with ``upright``): the cloud levelled
  (its up turned onto +y about its centroid), as that classifier was trained (levelled views,
  only their yaw free), its looks turned about +y; its log-probabilities are averaged with the
  other classifier's, whose errors differ (docs/classification.md). The upright card's threshold
  and accuracy are the pair's. Without an upright classifier the up does not enter.
* Several looks: a request in the accuracy mode (``ensemble: K``) is also classified K times, on
  its own random subset each and turned 360/K degrees about the cloud's z axis (so the
  canonicaliser starts from K poses, as the pose ensemble's runs do), the log-probabilities
  averaged: on validation views, 4 looks gained 2.2 points top-1 for ~4x the classification's
  time (docs/classification.md, ``benchmarks/classify_tta.py``).
* A second opinion: when one look leaves the answer unsure (below the threshold), the cloud
  gets ``SECOND_LOOKS`` - 1 more turned looks and the answer is theirs and the first's together
  (without ``up``, exactly what asking for that many looks gives), where the budget has room: they must be expected to
  end within the budget's first half (``second_look_deadline``), so the pose run keeps the
  rest. Sure answers (most) cost one look; the reply says ``second_opinion: true`` when it ran.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import viewing_axis_turns
from itnet.pose.cloud import Limits, validate_cloud, validate_up
from itnet.pose.errors import BadCloudError, NoClassifierError, NoPoseModelError
from itnet.pose.runtime import LoadedClassifier, LoadedModel
from itnet.preprocess import (
    DegenerateCloudError,
    Normalization,
    estimate_normalization,
    shuffled_subset,
)
from itnet.size_prior import metres_per_unit, with_size
from itnet.upright import UP, levelled, upright_starts

AUTO = "auto"
MAX_LOOKS = 16  # as many as the pose ensemble's runs
SECOND_LOOKS = 4  # the second opinion's looks, the first included (docs/classification.md)


def second_look_deadline(started: float, budget_ms: float) -> float:
    """When a request's second opinion must end (``time.perf_counter()`` seconds): within the
    first half of its budget, so the pose run keeps at least the other half."""
    return started + budget_ms / 2e3


@dataclass(frozen=True)
class Candidate:
    category: str
    probability: float


@dataclass(frozen=True)
class Recognition:
    """What the classifier says about one cloud: candidates (most probable first, ``top`` of
    them), whether the winner's probability is below the threshold, and the time it took."""

    candidates: list[Candidate]
    threshold: float
    elapsed_ms: float
    size_m: float | None = None  # the clouds' RMS radius in metres (mean), when the unit is known
    size_used: bool = False  # whether that size entered the probabilities (the card's prior)
    looks: int = 1  # inputs per cloud whose log-probabilities were averaged (turned subsets)
    upright: bool = False  # the upright classifier also saw the clouds, levelled by their up
    second_opinion: bool = False  # the first look was unsure: ``looks`` is the second opinion's

    @property
    def category(self) -> str:
        return self.candidates[0].category

    @property
    def probability(self) -> float:
        return self.candidates[0].probability

    @property
    def unsure(self) -> bool:
        return self.probability < self.threshold

    def as_dict(self) -> dict[str, Any]:
        """The reply's fields: category, category_probability, candidates, unsure, timing."""
        return {
            "category": self.category,
            "category_probability": round(self.probability, 6),
            "candidates": [
                {"category": c.category, "probability": round(c.probability, 6)}
                for c in self.candidates
            ],
            "unsure": self.unsure,
            "classify_ms": round(self.elapsed_ms, 3),
            **({} if self.size_m is None else {"size_m": round(self.size_m, 6)}),
            "size_used": self.size_used,
            **({"classify_looks": self.looks} if self.looks > 1 else {}),
            **({"classified_upright": True} if self.upright else {}),
            **({"second_opinion": True} if self.second_opinion else {}),
        }


def turned_looks(
    cloud: NDArray,
    looks: int,
    points: int,
    rng: np.random.Generator,
    up: NDArray | None = None,
    norm: Normalization | None = None,
) -> NDArray[np.float32]:
    """A cloud (N, 3), normalised unless ``norm`` is given -> (looks, points, 3): own random
    subsets (at most ``points`` each, in random order: ``shuffled_subset``), the k-th turned
    360k/looks degrees about z.
    ``up`` (3,, unit): the cloud levelled first (up onto +y), the turns about +y instead.
    ``norm``: the cloud is given in its own units, and only the chosen points are normalised
    (the same looks, without normalising the points no look keeps)."""
    subsets = [shuffled_subset(cloud, points, rng) for _ in range(looks)]
    if norm is not None:
        subsets = [norm.apply(subset) for subset in subsets]
    x = np.stack(subsets)
    if up is not None:
        x = levelled(x, up)  # row by row, so the same as levelling the whole cloud first
    x = x.astype(np.float32)
    if looks > 1:
        turns = viewing_axis_turns(looks) if up is None else upright_starts(UP, looks)
        x = np.einsum("kij,knj->kni", turns.astype(np.float32), x)
    return x


def mean_log_probability(probabilities: ArrayLike) -> NDArray[np.float64]:
    """Class probabilities of several looks (or classifiers) at the same input, (K, ..., C) ->
    their mean log-probability (..., C): the fused score, whose argmax is the fused class."""
    return np.log(np.maximum(np.asarray(probabilities, np.float64), 1e-12)).mean(axis=0)


def classify(
    classifier: LoadedClassifier,
    points: ArrayLike,
    top: int = 3,
    limits: Limits = Limits(),
    seed: int = 0,
    units: str | None = None,
    looks: int = 1,
    up: ArrayLike | None = None,
    second_looks: int = SECOND_LOOKS,
    deadline: float | None = None,
) -> Recognition:
    """A cloud (N, 3), any unit -> its Recognition. ``units``: the cloud's unit, if known (its
    size then counts, see the module); ``looks``: inputs averaged; ``up``: which way is up in
    the cloud, if known; ``second_looks``, ``deadline``: the second opinion (see the module).
    Raises BadCloudError for a bad cloud, unit, look count or up."""
    ups: list[ArrayLike | None] | None = None if up is None else [up]
    return classify_together(
        classifier, [points], top, limits, seed, units, looks, ups, second_looks, deadline
    )


def _look_probabilities(
    classifier: LoadedClassifier,
    upright: LoadedClassifier | None,
    cloud: NDArray,
    norm: Normalization,
    up: NDArray | None,
    looks: int,
    seed: int,
    skip: int = 0,
) -> NDArray:
    """One cloud's ``looks`` turned looks (drawn from ``seed``), less the first ``skip`` of
    them -> (L, C) class probabilities: the classifier's of each look, then, with ``upright``,
    the upright classifier's of each levelled look."""
    rng = np.random.default_rng(seed)
    x = turned_looks(cloud, looks, classifier.card.points, rng, norm=norm)[skip:]
    probs = classifier.probabilities(x)
    if upright is not None:
        stood = turned_looks(cloud, looks, upright.card.points, rng, up, norm)[skip:]
        probs = np.concatenate([probs, upright.probabilities(stood)])
    return probs


def classify_together(
    classifier: LoadedClassifier,
    clouds: list[ArrayLike],
    top: int = 3,
    limits: Limits = Limits(),
    seed: int = 0,
    units: str | None = None,
    looks: int = 1,
    ups: list[ArrayLike | None] | None = None,
    second_looks: int = SECOND_LOOKS,
    deadline: float | None = None,
) -> Recognition:
    """Several clouds of one object (e.g. the two clouds of an alignment) -> one Recognition:
    the product of the per-cloud probabilities (each the mean over ``looks`` turned subsets in
    the log domain, with its size's likelihood when ``units`` is given and the card has a size
    prior), renormalised. ``ups``: each cloud's up direction, where known; when every cloud has
    one and an upright classifier is loaded, it also classifies them levelled (see the module).
    ``second_looks`` K > 1: one look that leaves the answer unsure is followed by K - 1 more,
    turned, when they are expected to end by ``deadline`` (``time.perf_counter()`` seconds;
    None: no limit), and the answer is the K looks' (see the module). Raises BadCloudError."""
    start = time.perf_counter()
    for name, count in (("looks", looks), ("second_looks", second_looks)):
        if not 1 <= count <= MAX_LOOKS:
            raise BadCloudError(f"{name} must be in [1, {MAX_LOOKS}], got {count}")
    levels: list[NDArray | None] = [None] * len(clouds)
    if ups is not None and len(ups) != len(clouds):
        raise BadCloudError(f"{len(ups)} up directions for {len(clouds)} clouds")
    upright = classifier.upright
    if ups is not None and upright is not None and all(u is not None for u in ups):
        levels = [validate_up(u) for u in ups if u is not None]
    else:
        upright = None
    card = classifier.card if upright is None else upright.card  # the threshold, the prior
    try:
        to_metres = None if units is None else metres_per_unit(units)
    except ValueError as err:
        raise BadCloudError(str(err)) from None
    prior = classifier.card.size_prior if to_metres is not None else None
    prepared = []
    for points in clouds:
        cloud = validate_cloud(points, limits)
        try:
            prepared.append((cloud, estimate_normalization(cloud)))
        except DegenerateCloudError as err:
            raise BadCloudError(str(err)) from None
    sizes = [norm.scale * to_metres for _, norm in prepared] if to_metres is not None else []

    def fused(per_cloud: list[NDArray]) -> NDArray:
        """Each cloud's looks' probabilities (L, C) -> the renormalised product over clouds."""
        log_probs = np.zeros(len(classifier.card.classes))
        for k, probs in enumerate(per_cloud):
            own = mean_log_probability(probs)
            log_probs += own if prior is None else with_size(own, prior, sizes[k])
        probs = np.exp(log_probs - log_probs.max())
        return probs / probs.sum()

    per_cloud = [
        _look_probabilities(classifier, upright, cloud, norm, up, looks, seed)
        for (cloud, norm), up in zip(prepared, levels, strict=True)
    ]
    probs, second = fused(per_cloud), False
    if looks == 1 and second_looks > 1 and probs.max() < card.threshold:
        expected_s = (time.perf_counter() - start) * (second_looks - 1)  # as long a look each
        if deadline is None or time.perf_counter() + expected_s <= deadline:
            per_cloud = [
                np.concatenate([probs, _look_probabilities(
                    classifier, upright, cloud, norm, up, second_looks, seed, skip=1)])
                for probs, (cloud, norm), up in zip(per_cloud, prepared, levels, strict=True)
            ]  # fmt: skip
            probs, looks, second = fused(per_cloud), second_looks, True
    order = np.argsort(-probs, kind="stable")[: max(1, top)]
    candidates = [Candidate(classifier.card.classes[i], float(probs[i])) for i in order]
    elapsed_ms = (time.perf_counter() - start) * 1e3
    size = float(np.mean(sizes)) if sizes else None
    return Recognition(candidates, card.threshold, elapsed_ms, size, prior is not None, looks,
                       upright is not None, second)  # fmt: skip


def pose_model_for(category: str, models: dict[str, LoadedModel]) -> LoadedModel | None:
    """The loaded pose model of a category: the one named after it, else the first (by name)
    whose card has that category, else None."""
    if category in models and models[category].card.category == category:
        return models[category]
    return next((models[n] for n in sorted(models) if models[n].card.category == category), None)


def recognise(
    classifier: LoadedClassifier | None,
    models: dict[str, LoadedModel],
    points: ArrayLike,
    limits: Limits = Limits(),
    units: str | None = None,
    looks: int = 1,
    up: ArrayLike | None = None,
    second_looks: int = SECOND_LOOKS,
    deadline: float | None = None,
) -> tuple[Recognition, LoadedModel]:
    """Classify a cloud (``looks`` times, levelled by ``up`` where given and an upright
    classifier is loaded, a second opinion of ``second_looks`` when unsure and it ends by
    ``deadline``; see the module) and pick its pose model. Raises
    NoClassifierError when none is loaded, BadCloudError, NoPoseModelError when the category
    has no model."""
    if classifier is None:
        raise NoClassifierError(
            'model "auto" needs the category classifier, and none is loaded; name a model '
            f"({', '.join(sorted(models))})",
        )
    recognition = classify(
        classifier, points, limits=limits, units=units, looks=looks, up=up,
        second_looks=second_looks, deadline=deadline,
    )  # fmt: skip
    model = pose_model_for(recognition.category, models)
    if model is None:
        candidates = ", ".join(f"{c.category} {c.probability:.2f}" for c in recognition.candidates)
        raise NoPoseModelError(
            f"the cloud looks like a {recognition.category} (probability "
            f"{recognition.probability:.2f}; candidates: {candidates}), and no {recognition.category} "
            f"pose model is loaded (loaded: {', '.join(sorted(models))})",
        )
    return recognition, model
