"""The data of one training run over one or several categories: shapes in each category's
canonical frame, how often each is drawn, each one's symmetry turns, and the fixed validation
scans of every category.

Categories are drawn uniformly (then a shape of the category), so a category with 106 shapes
(bathtub) is trained as often as one with 889 (chair): each gets fresh random views every step.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.model.categories import Category, category
from itnet.model.data import ScanSet, cached_scan_set, load_shapes, split_files
from itnet.model.scanner import ScanConfig
from itnet.model.shapes import Shape
from itnet.symmetry import symmetry_group

LOSS_YAW_SAMPLES = 12  # turns (30 degrees apart) standing in for the continuous group in the loss
ALL_MODELNET10 = "modelnet10"


def category_names(spec: str, data: Path) -> list[str]:
    """'chair' -> ['chair']; 'sofa,chair' -> both; 'modelnet10' -> every sub-folder of DATA
    that has train/ and test/ (sorted)."""
    if spec == ALL_MODELNET10:
        return sorted(d.name for d in data.iterdir() if (d / "train").is_dir())
    return [name.strip() for name in spec.split(",") if name.strip()]


@dataclass
class CategorySet:
    """shapes (M,), draw probability (M,), symmetry turns (M, G, 4, 4) per shape; validation
    scans and the Category of each category by name."""

    categories: dict[str, Category]
    shapes: list[Shape]
    probabilities: NDArray[np.float64]
    turns: NDArray[np.float32]
    validation: dict[str, ScanSet]
    orientation: dict[str, dict]

    def draw(self, rng: np.random.Generator, batch: int) -> NDArray[np.int64]:
        """Indices (batch,) of the shapes to scan for one training step."""
        if len(self.categories) == 1:  # a single category: the chair's original uniform draw
            return rng.integers(len(self.shapes), size=batch)
        return rng.choice(len(self.shapes), size=batch, p=self.probabilities)


def test_scans(
    data: Path,
    cat: Category,
    views: int,
    seed: int,
    scan: ScanConfig,
    cache: Path,
    frame: str = "modelnet",
    check_orientation: bool = True,
) -> tuple[ScanSet, dict]:
    """A category's fixed, seeded test scans (cached), its shapes in the category's frame and
    orientation-checked as training does. Returns (scans, orientation-check counts)."""
    files = split_files(data, cat.name, 0.1, 0)["test"]
    if not files:
        raise ValueError(f"{data}: no test shapes of {cat.name}")
    return _scans_of(files, cat, views, seed, scan, cache, frame, check_orientation)


def _scans_of(files: list[Path], cat: Category, views: int, seed: int, scan: ScanConfig,
              cache: Path, frame: str, check_orientation: bool) -> tuple[ScanSet, dict]:  # fmt: skip
    """Seeded scans (cached) of the shapes in ``files``, in the category's frame and
    orientation-checked as training does -> (scans, orientation-check counts)."""
    shapes, orientation = load_shapes(
        files, frame, cache, check_orientation, cat.quarter_turns, cat.symmetry
    )
    return cached_scan_set(shapes, views, seed, scan, cache), orientation


def validation_scans(
    data: Path,
    cat: Category,
    views: int = 4,
    seed: int = 0,
    scan: ScanConfig | None = None,
    cache: Path = Path("cache"),
    frame: str = "modelnet",
    check_orientation: bool = True,
    validation_fraction: float = 0.1,
) -> ScanSet:
    """A category's fixed validation scans (cached): its held-out training shapes
    (``validation_fraction``, split by ``seed``), ``views`` each, seeded ``seed + 7``: what
    ``itnet train`` validates on (with its defaults)."""
    files = split_files(data, cat.name, validation_fraction, seed)["val"]
    shapes, _ = load_shapes(files, frame, cache, check_orientation, cat.quarter_turns, cat.symmetry)
    if not shapes:  # every one dropped by the orientation check: the caller says why
        return ScanSet([], np.empty((0, 4, 4)), np.empty(0), [])
    return cached_scan_set(shapes, views, seed + 7, scan or ScanConfig(), cache)


def training_scans(
    data: Path,
    cat: Category,
    views: int,
    seed: int,
    scan: ScanConfig,
    cache: Path,
    frame: str = "modelnet",
    check_orientation: bool = True,
    validation_fraction: float = 0.1,
    split_seed: int = 0,
) -> ScanSet:
    """Fixed, seeded scans (cached) of a category's training shapes, without its validation
    shapes (``validation_fraction``, split by ``split_seed`` as ``validation_scans`` splits):
    for what is fitted on the training split after the network (``itnet centre-fit``)."""
    files = split_files(data, cat.name, validation_fraction, split_seed)["train"]
    return _scans_of(files, cat, views, seed, scan, cache, frame, check_orientation)[0]


def _turns(symmetry: str, size: int) -> NDArray[np.float32]:
    """A symmetry's turns as (size, 4, 4) homogeneous rotations, cycled to fill ``size``."""
    rotations = symmetry_group(symmetry, LOSS_YAW_SAMPLES)
    out = np.tile(np.eye(4, dtype=np.float32), (size, 1, 1))
    out[:, :3, :3] = rotations[np.arange(size) % len(rotations)]
    return out


def load_category_set(
    data: Path,
    names: list[str],
    frame: str,
    cache: Path,
    check_orientation: bool,
    validation_fraction: float,
    seed: int,
    val_views: int,
    val_scan: ScanConfig,
    symmetry: str | None = None,
) -> CategorySet:
    """Load every category's training shapes and fixed validation scans (cached).
    ``symmetry`` overrides the table's (a user's own single category)."""
    cats = {name: category(name, symmetry) for name in names}
    group = max(len(symmetry_group(c.symmetry, LOSS_YAW_SAMPLES)) for c in cats.values())
    shapes: list[Shape] = []
    probabilities: list[NDArray] = []
    turns: list[NDArray] = []
    validation, orientation = {}, {}
    for name, cat in cats.items():
        files = split_files(data, name, validation_fraction, seed)
        load = {"quarter_turns": cat.quarter_turns, "symmetry": cat.symmetry}
        train, orientation[name] = load_shapes(
            files["train"], frame, cache, check_orientation, **load
        )
        validation[name] = validation_scans(
            data, cat, val_views, seed, val_scan, cache, frame, check_orientation,
            validation_fraction,
        )  # fmt: skip
        if not train or not validation[name].clouds:
            raise ValueError(
                f"{name}: the orientation check kept {len(train)} training and "
                f"{len(validation[name].clouds) // val_views} "
                f"validation shapes ({orientation[name]}); if the shapes look alike turned about "
                f"up, give the category its symmetry (--symmetry yaw180, yaw90 or yaw)"
            )
        shapes += train
        probabilities.append(np.full(len(train), 1.0 / (len(cats) * len(train))))
        turns.append(np.repeat(_turns(cat.symmetry, group)[None], len(train), axis=0))
    return CategorySet(
        cats,
        shapes,
        np.concatenate(probabilities),
        np.concatenate(turns),
        validation,
        orientation,
    )
