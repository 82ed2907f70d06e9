"""Fit the classifier's size prior (``itnet.size_prior``) on training views and measure it.

ModelNet10's files keep their models' own scale (``shapes.to_canonical`` returns it beside the
unit-radius shape), and most of its models are in inches: a chair's bounding radius is about 24
units, a bed's 58, a night stand's 19, a dresser's 30 (medians of the training split; about one
model in ten is at another scale, which the prior's robust fit and heavy tails absorb). So a view
of a shape in metres is the unit-radius scan times the model's radius times 0.0254.

* Fit: ``views`` random views (half occluded, half the paper's, as the classifier was trained)
  of every training shape -> per class the robust centre and spread of log RMS radius.
* Real sizes (``rules`` and ``real=True``): each view's shape drawn at a real piece's bounding
  radius (uniform in ``model.categories.REAL_RADIUS_M``, as furniture is made, not as the file
  was modelled), by the named view rules (``RULE+SENSOR``: by that depth camera at that size).
* Measure: fixed views of the validation (or test) shapes, classified by the exported graph
  with and without the size (the same views, so the difference is paired).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.cloud_io import read_cloud
from itnet.model.categories import real_radius_m
from itnet.model.classify.data import (
    LabelledShapes,
    normalised_view,
    shuffled_views,
    view_configs,
)
from itnet.model.data import split_files
from itnet.model.scanner import ScanConfig, scan_of
from itnet.model.shapes import to_canonical
from itnet.model_card import SizePrior
from itnet.pose.runtime import LoadedClassifier
from itnet.preprocess import estimate_normalization
from itnet.size_prior import with_size

INCH_M = 0.0254  # ModelNet's unit, read as inches


@dataclass
class SizedViews:
    """Views of labelled shapes: normalised points (V, N, 3) (or None), labels (V,), and each
    view's RMS radius about its centroid in metres (V,)."""

    points: NDArray[np.float32] | None
    labels: NDArray[np.int64]
    radii_m: NDArray[np.float64]


def source_radii(data: Path, classes: list[str], split: str, seed: int = 0) -> list[float]:
    """Each shape's bounding radius in its file's own units, in ``load_splits``' order."""
    return [
        to_canonical(read_cloud(f), "modelnet")[1]
        for name in classes
        for f in split_files(data, name, 0.1, seed)[split]
    ]


def at_real_size(
    config: ScanConfig, category: str, rng: np.random.Generator
) -> tuple[ScanConfig, float]:
    """A real piece of ``category``'s bounding radius in metres, drawn from its range
    (``real_radius_m``), and ``config`` with a depth camera's object at that size (a clean
    render's as it is)."""
    metres = float(rng.uniform(*real_radius_m(category)))
    if config.sensor != "clean":
        config = replace(config, radius_m=(metres, metres))
    return config, metres


def sized_views(
    shapes: LabelledShapes,
    radii: list[float],
    views: int,
    seed: int,
    points: int | None = None,
    unit_m: float = INCH_M,
    rules: tuple[str, ...] = ("occluded", "paper"),
    real: bool = False,
) -> SizedViews:
    """``views`` views per shape, by the view ``rules`` in turn (``view_configs``), each shape
    at its file's size read in ``unit_m`` (``radii``: the files' bounding radii) or, ``real``,
    at a real piece's size (``shapes.names`` needed); with ``points``, also each view
    normalised and resampled as the classifier sees it."""
    rng = np.random.default_rng(seed)
    configs = view_configs(rules)
    xs, labels, sizes = [], [], []
    for shape, label, radius in zip(shapes.shapes, shapes.labels, radii, strict=True):
        for v in range(views):
            config = configs[v % len(configs)]
            if real:  # the shape's bounding radius in metres, also the camera's
                config, metres = at_real_size(config, shapes.names[label], rng)
            else:
                metres = radius * unit_m
            cloud, _ = scan_of(shape, rng, config)
            sizes.append(estimate_normalization(cloud).scale * metres)
            labels.append(label)
            if points is not None:
                xs.append(normalised_view(cloud, points, rng))
    x = np.stack(xs) if points is not None else None
    return SizedViews(x, np.asarray(labels, np.int64), np.asarray(sizes))


def accuracy_with_and_without(
    classifier: LoadedClassifier, views: SizedViews, prior: SizePrior
) -> dict[str, float]:
    """Top-1 and mean class accuracy of the graph alone and with the size, on the same views;
    the paired gain in top-1 with its standard error."""
    assert views.points is not None
    x = shuffled_views(views.points, np.random.default_rng(0))  # in random order, as served
    probs = np.concatenate(
        [classifier.probabilities(x[i : i + 128]) for i in range(0, len(views.labels), 128)]
    )
    log_probs = np.log(np.maximum(probs, 1e-12))
    sized = np.stack([with_size(lp, prior, r) for lp, r in zip(log_probs, views.radii_m)])
    alone = probs.argmax(1) == views.labels
    both = sized.argmax(1) == views.labels
    classes = np.unique(views.labels)
    gain = both.astype(float) - alone.astype(float)
    return {
        "views": len(views.labels),
        "top1": round(float(alone.mean()), 4),
        "top1_with_size": round(float(both.mean()), 4),
        "mean_class": round(float(np.mean([alone[views.labels == c].mean() for c in classes])), 4),
        "mean_class_with_size": round(
            float(np.mean([both[views.labels == c].mean() for c in classes])), 4
        ),
        "gain": round(float(gain.mean()), 4),
        "gain_stderr": round(float(gain.std() / math.sqrt(len(gain))), 4),
    }
