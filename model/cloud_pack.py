"""A compact, lossy-by-design pack of point-cloud shapes, to carry a dataset to another machine.

A leased GPU machine takes the repository and little beside it (64 MiB in all here), and the
ModelNet10 clouds are ~50 MB as float32. A pack stores each shape's points on a 16-bit grid over
its own bounding box (grid error ≤ 1/131,070 of the box's side, ~0.004 mm on a 50 cm chair: far
below the training scans' depth noise; the decoded float32 adds its own rounding, which for a
cloud far from the origin can exceed the grid's), sorted in Morton order and delta-coded so that LZMA
shrinks them to about half of the raw 16-bit size. Point order carries no meaning in a cloud.

``pack(root, categories)`` reads ``root/CATEGORY/{train,test}/*`` (any cloud format
``itnet.cloud_io`` reads); ``unpack(path, root)`` writes the same layout back as ``.npy`` files,
which the trainers read like the originals. ``pack(..., splits=("train",))`` leaves the test
split out (a machine that only trains never reads it; ModelNet10's is a fifth of the shapes):
its folders come back empty, so the trainers still see ModelNet's layout and the same
train/validation split.
"""

from __future__ import annotations

import io
import lzma
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.cloud_io import read_cloud
from itnet.model.shapes import list_shape_files

LEVELS = 65535  # the grid's steps per box side
SPLITS = ("train", "test")


def _morton(q: NDArray[np.uint16]) -> NDArray[np.uint64]:
    """Grid points (N, 3) -> Morton codes (N,): the three coordinates' bits interleaved."""
    code = np.zeros(len(q), np.uint64)
    for axis in range(3):
        v = q[:, axis].astype(np.uint64)
        for bit in range(16):
            code |= ((v >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return code


def encode(points: NDArray, levels: int = LEVELS) -> tuple[NDArray[np.float64], NDArray[np.int16]]:
    """Points (N, 3) -> (box (2, 3): low and high corners, deltas (N, 3) int16), on a grid of
    ``levels`` steps per side (at most 65,535; fewer compress better: 4,095 takes a quarter
    less room at 1/8,190 of the side)."""
    if not 1 <= levels <= LEVELS:
        raise ValueError(f"levels must be in 1..{LEVELS}, got {levels}")
    points = np.asarray(points, np.float64)
    low, high = points.min(0), points.max(0)
    side = np.where(high > low, high - low, 1.0)
    q = np.round((points - low) / side * levels).astype(np.uint16)
    q = q[np.argsort(_morton(q), kind="stable")]
    deltas = np.diff(q.astype(np.int32), axis=0, prepend=0).astype(np.int16)  # wraps mod 2^16
    return np.stack([low, high]), deltas


def decode(box: NDArray, deltas: NDArray[np.int16], levels: int = LEVELS) -> NDArray[np.float32]:
    """Inverse of ``encode``, up to the grid: (2, 3), (N, 3) -> points (N, 3) float32."""
    q = np.cumsum(deltas.astype(np.int64), axis=0) % 65536
    low, high = box
    side = np.where(high > low, high - low, 1.0)
    return (low + q / levels * side).astype(np.float32)


def pack(root: Path, categories: list[str], out: Path, levels: int = LEVELS,
         splits: tuple[str, ...] = SPLITS) -> dict[str, int]:  # fmt: skip
    """Every shape of ``splits`` of ``categories`` under ``root`` -> one LZMA-compressed file at
    ``out``, on a grid of ``levels`` steps per box side. Returns the number of shapes per
    category."""
    if not splits or set(splits) - set(SPLITS):
        raise ValueError(f"splits must be some of {SPLITS}, got {splits}")
    names, boxes, counts, deltas, per_category = [], [], [], [], {}
    seen: set[str] = set()
    for category in categories:
        per_category[category] = 0
        for split in splits:
            folder = root / category / split
            for path in list_shape_files(folder):
                name = f"{category}/{split}/{path.relative_to(folder).with_suffix('').as_posix()}"
                if name in seen:
                    raise ValueError(f"{path}: two shapes would unpack to {name}.npy")
                seen.add(name)
                box, coded = encode(read_cloud(path), levels)
                names.append(name)
                boxes.append(box)
                counts.append(len(coded))
                deltas.append(coded.T)  # planar: x deltas, then y, then z
                per_category[category] += 1
    if not names:
        raise ValueError(f"{root}: no shapes of {', '.join(categories)}")
    buffer = io.BytesIO()
    np.savez(
        buffer,
        names=np.array(names),
        boxes=np.stack(boxes),
        counts=np.array(counts, np.int64),
        deltas=np.concatenate(deltas, axis=1),
        levels=np.array(levels),
        categories=np.array(categories),
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(lzma.compress(buffer.getvalue(), preset=9))
    return per_category


def unpack(path: Path, root: Path) -> int:
    """A pack -> ``root/CATEGORY/SPLIT/NAME.npy`` (float32 points), every split's folder made
    even where the pack holds none of it; returns the shape count."""
    with np.load(io.BytesIO(lzma.decompress(path.read_bytes()))) as stored:
        names, boxes, counts, deltas = (stored[k] for k in ("names", "boxes", "counts", "deltas"))
        levels = int(stored["levels"]) if "levels" in stored else LEVELS
        categories = list(stored["categories"]) if "categories" in stored else []
    for category in {*categories, *(str(n).split("/")[0] for n in names)}:
        for split in SPLITS:
            (root / category / split).mkdir(parents=True, exist_ok=True)
    for name, box, end, count in zip(names, boxes, np.cumsum(counts), counts):
        target = root / f"{name}.npy"
        target.parent.mkdir(parents=True, exist_ok=True)
        np.save(target, decode(box, deltas[:, end - count : end].T, levels))
    return len(names)
