"""Partial, unaligned views of every ModelNet10 class, labelled by class, for the classifier.

* Shapes: ``split_files`` per class (the dataset's train/test split, validation carved out of
  train), loaded in ModelNet's frame without orientation checks (views are in full SO(3), so the
  frame does not matter for the label).
* Views: the project's scanner, half occluded views, half ``PAPER_VIEWS`` (as pose training), or
  other view rules, from any direction or from a camera above the shape's horizon
  (``view_configs``), as rendered or by a depth camera (``RULE+SENSOR``, ``model.sensor``): each
  shape then at its class's real size (``model.categories.real_radius_m``), seen from 1-6 m.
  Training views are fresh every step (seeded per step, so a resumed run sees the same data);
  validation and test views are fixed and cached.
* Every view is normalised as the runtime does (``itnet.preprocess``) and resampled to a fixed
  point count (repeats do not change a max-pooled feature).
* Upright views (``upright`` set): each view is levelled by its up direction as a caller with a
  gravity sensor would give it (the truth tilted by a few degrees, ``itnet.upright``), so the
  classifier sees standing objects with only their yaw unknown, as the service does for a
  request that gives ``up``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.model.categories import real_radius_m
from itnet.model.data import cached_scan_set, load_shapes, split_files
from itnet.model.scanner import (
    VIEW_RULES,
    ScanConfig,
    room_cut,
    scan_config,
    scan_of,
    view_name_parts,
)
from itnet.model.shapes import Shape, random_stretch, stretched
from itnet.preprocess import estimate_normalization, resample
from itnet.upright import levelled, sensed_ups, tilted


def class_names(data: Path) -> list[str]:
    """The class folders of a ModelNet-style root, sorted (the label order)."""
    names = sorted(p.name for p in data.iterdir() if p.is_dir())
    if not names:
        raise ValueError(f"{data}: no class folders")
    return names


@dataclass
class LabelledShapes:
    """Shapes of one split with their class index (labels (S,) int64) and the class names
    (``names[label]``; what gives views by a depth camera their real size)."""

    shapes: list[Shape]
    labels: NDArray[np.int64]
    names: tuple[str, ...] = ()

    def sized(self, config: ScanConfig, label: int) -> ScanConfig:
        """``config`` for a shape of class ``label``: by a depth camera, at the class's real
        size; a rendered view as it is."""
        if config.sensor == "clean":
            return config
        if not self.names:
            raise ValueError("views by a depth camera need the class names (LabelledShapes.names)")
        return replace(config, radius_m=tuple(real_radius_m(self.names[label])))


def load_splits(
    data: Path, classes: list[str], validation_fraction: float, seed: int, cache: Path
) -> dict[str, LabelledShapes]:
    """{'train', 'val', 'test'} -> labelled shapes of every class."""
    splits: dict[str, LabelledShapes] = {}
    per_class = [split_files(data, name, validation_fraction, seed) for name in classes]
    for split in ("train", "val", "test"):
        shapes, labels = [], []
        for label, files in enumerate(per_class):
            loaded, _ = load_shapes(files[split], "modelnet", cache, check_orientation=False)
            shapes += loaded
            labels += [label] * len(loaded)
        splits[split] = LabelledShapes(shapes, np.array(labels, dtype=np.int64), tuple(classes))
    return splits


def normalised_view(cloud: NDArray, points: int, rng: np.random.Generator) -> NDArray[np.float32]:
    """A scan (K, 3), any unit -> (points, 3) float32, normalised as the runtime does."""
    return resample(estimate_normalization(cloud).apply(cloud), points, rng)


def shuffled_views(x: NDArray[np.float32], rng: np.random.Generator) -> NDArray[np.float32]:
    """Views (V, N, 3) -> each one's points in its own random order, as the service feeds them
    (``itnet.preprocess.shuffled_subset``): a run's fixed views pad a small view with repeats
    after its points in scan order, and a graph whose canonicaliser sees only the first points
    (``ClassifierCard.canonical_points``) must not see one end of the scan."""
    return np.stack([view[rng.permutation(len(view))] for view in x])


def training_batch(
    data: LabelledShapes,
    batch: int,
    points: int,
    rng: np.random.Generator,
    configs: list[ScanConfig],
    balanced: bool = False,
    stretch: float = 1.0,
    upright: float | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.int64], NDArray[np.float32]]:
    """Fresh random views -> (points (B, points, 3), labels (B,), up (B, 3)): ``up`` is the
    shape's up axis (the canonical +y; ModelNet10's shapes all stand upright in their files) as
    a unit vector in the view's frame, for a loss that teaches the transformer to stand views
    up. Shapes are drawn uniformly, so classes come in proportion to their share of the split;
    ``balanced``: each view's class is drawn uniformly, then one of its shapes (ModelNet10's
    training split has 106 bathtubs and 889 chairs, its test split 50-100 shapes of every
    class). ``stretch`` > 1: each shape is first stretched along its axes by factors drawn
    log-uniformly in [1/stretch, stretch] (``shapes.stretched``). ``upright`` (degrees): each
    view levelled by its up direction tilted by an error drawn uniformly in [0, upright] (the
    returned ``up`` is then the true up in the levelled view, near +y)."""
    if balanced:
        classes = np.unique(data.labels)
        index = np.array(
            [rng.choice(np.flatnonzero(data.labels == c)) for c in rng.choice(classes, batch)]
        )
    else:
        index = rng.integers(len(data.shapes), size=batch)
    x = np.empty((batch, points, 3), np.float32)
    up = np.empty((batch, 3), np.float32)
    for b, i in enumerate(index):
        shape = data.shapes[i]
        if stretch > 1:
            shape = stretched(shape, random_stretch(rng, stretch))
        config = data.sized(configs[int(rng.integers(len(configs)))], int(data.labels[i]))
        cloud, canonical_from_view = scan_of(shape, rng, config)
        x[b] = normalised_view(cloud, points, rng)  # a shift and a scale: directions keep
        up[b] = canonical_from_view[1, :3]  # R^T e_y: the canonical +y in the view's frame
        if upright is not None:
            given = tilted(up[b : b + 1], rng.uniform(0.0, upright), rng)[0]
            x[b], up[b] = levelled(x[b], given), levelled(up[b : b + 1], given)[0]
    return x, data.labels[index], up


def view_configs(
    rules: tuple[str, ...] = ("occluded", "paper"), elevation: tuple[float, float] | None = None
) -> list[ScanConfig]:
    """The scanner settings of named view rules (``VIEW_RULES``; ``RULE+SENSOR``: by that depth
    camera, the size left to ``LabelledShapes.sized``; ``RULE+SENSOR+crop``: cut out of a
    room; ``+clutter``: a furnished one), each from any direction or, with ``elevation``
    (degrees), from a camera that high over the shape's horizon."""
    extra = {} if elevation is None else {"elevation": tuple(elevation)}
    configs = []
    for name in rules:
        rule, sensor, crop = view_name_parts(name)
        camera = {"sensor": sensor, "surroundings": room_cut(crop)} if sensor else {}
        configs.append(scan_config(VIEW_RULES[rule], camera, extra))
    return configs


def fixed_views(
    data: LabelledShapes,
    views: int,
    points: int,
    seed: int,
    cache: Path,
    upright: float | None = None,
    configs: list[ScanConfig] | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """``views`` fixed views per shape, shared among ``configs`` (default: occluded and the
    paper's; at least one each) -> (points (V, points, 3), labels (V,)). The scans are cached.
    ``upright`` (degrees): each view levelled by its up direction tilted by exactly that error,
    in a seeded direction."""
    configs = view_configs() if configs is None else configs
    per_config = max(1, views // len(configs))
    xs, ys = [], []
    rng = np.random.default_rng(seed + 11)
    for k, config in enumerate(configs):
        # a rendered view's scans in one set; a camera's per class (each at its real size)
        groups = [np.arange(len(data.shapes))] if config.sensor == "clean" else [
            np.flatnonzero(data.labels == label) for label in np.unique(data.labels)
        ]  # fmt: skip
        for g, group in enumerate(groups):
            sized = data.sized(config, int(data.labels[group[0]]))
            shapes = [data.shapes[i] for i in group]
            scans = cached_scan_set(shapes, per_config, seed + k + 101 * g, sized, cache)
            clouds = [normalised_view(c, points, rng) for c in scans.clouds]
            if upright is not None:
                ups = sensed_ups(scans.poses, upright, np.random.default_rng(seed + 17 + k + g))
                clouds = [
                    levelled(c, u).astype(np.float32) for c, u in zip(clouds, ups, strict=True)
                ]
            xs += clouds
            ys.append(np.repeat(data.labels[group], per_config))
    return np.stack(xs), np.concatenate(ys)
