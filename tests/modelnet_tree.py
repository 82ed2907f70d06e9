"""A ModelNet-style tree of synthetic clouds for the tests: ``root/CLASS/{train,test}/*.npy``."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

MakeCloud = Callable[[np.random.Generator], np.ndarray]


def write_modelnet_tree(
    root: Path,
    classes: Mapping[str, MakeCloud],
    rng: np.random.Generator,
    train: int,
    test: int,
) -> Path:
    """``train`` and ``test`` clouds of every class, each made by ``classes[name](rng)``, saved
    as ``root/name/split/name_0000.npy``; returns ``root``."""
    for name, make in classes.items():
        for split, count in (("train", train), ("test", test)):
            folder = root / name / split
            folder.mkdir(parents=True)
            for i in range(count):
                np.save(folder / f"{name}_{i:04d}.npy", make(rng))
    return root
