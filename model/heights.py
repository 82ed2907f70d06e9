"""The height table of ``itnet.scene.height_prior``, measured: each category's training shapes'
extent along ModelNet's up (+z), their units read as inches (as the classifier's size prior reads
them).

    itnet fit heights --data ../shared/data/modelnet10
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from itnet.cloud_io import read_cloud
from itnet.model.classify.size_prior import INCH_M
from itnet.model.shapes import list_shape_files
from itnet.size_prior import log_median_and_spread


def measure(data: Path) -> dict[str, tuple[float, float]]:
    """Per category of a ModelNet-style root (DATA/CATEGORY/train/*): (median height in metres,
    robust spread of its log: 1.4826 x MAD)."""
    table = {}
    for folder in sorted(p for p in data.iterdir() if (p / "train").is_dir()):
        heights = [np.ptp(read_cloud(f)[:, 2]) * INCH_M for f in list_shape_files(folder / "train")]
        median, spread = log_median_and_spread(np.log(np.maximum(heights, 1e-6)))
        table[folder.name] = (round(float(np.exp(median)), 2), round(spread, 2))
    return table
