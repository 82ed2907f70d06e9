"""Objects standing against each other: a cluster cut in two where a learned judge finds that
it holds two.

Two objects a few centimetres apart (chairs at a table) make one cluster: their voxels link
across the gap. Two pieces of furniture that do not touch can be parted by a vertical plane,
and a plane through the gap between them crosses few of the points a camera sees. For each of
``DIRECTIONS`` directions along the floor, the plane across it whose strip (``STRIP_M`` wide)
holds fewest points for the points on its lesser side (at least ``MIN_SIDE`` of them) is a
candidate; the ``CANDIDATES`` best, at least ``SPREAD_DEG`` apart, are described by
``cut_features`` (how empty the strip is; the two parts' heights, bases and extents; the cut
against the camera's line of sight; ...). A plane through one object also crosses few points
where occlusion left a gap in it, so the cut judge (a ``FeatureNetwork`` fitted on the clusters
of scenes of training shapes, touching and not: ``itnet fit touching-cut``)
gives each candidate the probability that it parts two objects. The likeliest cut is made where
that probability reaches the judge's threshold, and each part is judged again (three objects in
a row), down to ``MIN_POINTS`` points.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.columns import percentiles
from itnet.planes import Plane, floor_axes
from itnet.scene.feature_network import FeatureNetwork

FILE = Path(__file__).with_name("touching_cut.json")
CLASSES = ("one", "two")  # the judge's classes: the cut crosses one object, or parts two
DIRECTIONS = 36  # planes' directions along the floor, over half a turn
BIN_M = 0.005
STRIP_BINS = 6  # the strip a cut should leave empty: 3 cm
MIN_SIDE = 0.1  # the lesser side of a cut holds at least this share of the points
MIN_PART = 3  # and, counted point by point (a histogram's bin may hold them all), this many
CANDIDATES = 6
SPREAD_DEG = 15.0
SAMPLE = 2048  # a larger cluster's candidates are found on this many of its points
MIN_POINTS = 160  # a smaller cluster is not cut
CUTS_DEEP = 2  # a part is judged again, once
ORIGIN = np.zeros(3)


@dataclass(frozen=True)
class Cut:
    """A vertical plane through a cluster: ``normal`` (3,) along the floor; the points p with
    p · normal < ``offset`` are on one side. ``features`` (F,): what the judge sees."""

    normal: NDArray[np.float64]
    offset: float
    features: NDArray[np.float64]

    def side(self, points: NDArray) -> NDArray[np.bool_]:
        """Points (K, 3) -> whether each is on the cut's first side (K,)."""
        return np.asarray(points, dtype=np.float64) @ self.normal < self.offset


def cut_candidates(
    points: NDArray, floor: Plane, viewpoint: NDArray = ORIGIN
) -> list[Cut]:  # fmt: skip
    """A cluster (K, 3) standing on ``floor``, the camera at ``viewpoint`` (3,) -> up to
    ``CANDIDATES`` cuts, emptiest first (see the module); none where no direction leaves
    ``MIN_SIDE`` of the points on each side."""
    full = np.asarray(points, dtype=np.float64)
    p = full[np.linspace(0, len(full) - 1, SAMPLE).astype(int)] if len(full) > SAMPLE else full
    n = len(p)
    a, b = floor_axes(floor.normal)
    flat = np.stack([p @ a, p @ b], axis=1)
    angles = np.arange(DIRECTIONS) * math.pi / DIRECTIONS
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    along = flat @ directions.T  # (n, D)
    lo = along.min(axis=0)
    bins = ((along - lo) / BIN_M).astype(np.int64)
    width = int(bins.max()) + 2
    hist = np.bincount((bins + np.arange(DIRECTIONS) * width).ravel(),
                       minlength=DIRECTIONS * width).reshape(DIRECTIONS, width).astype(float)  # fmt: skip
    total = np.concatenate([np.zeros((DIRECTIONS, 1)), np.cumsum(hist, axis=1)], axis=1)
    at = np.arange(width)
    half = STRIP_BINS // 2
    strip = total[:, np.minimum(at + half, width)] - total[:, np.maximum(at - half, 0)]
    left = total[:, 1:] - hist / 2
    lesser = np.minimum(left, n - left)
    score = np.where(lesser >= MIN_SIDE * n, strip / np.maximum(lesser, 1.0), np.inf)
    where = score.argmin(axis=1)
    best = score[np.arange(DIRECTIONS), where]
    offsets = lo + (where + 0.5) * BIN_M
    first = (along < offsets).sum(axis=0)  # the points each direction's cut leaves first
    parted = (first >= MIN_PART) & (n - first >= MIN_PART)  # not where they share one bin
    chosen: list[int] = []
    for j in np.argsort(best, kind="stable"):
        if not np.isfinite(best[j]) or len(chosen) == CANDIDATES:
            break
        if parted[j] and all(_apart(angles[j], angles[k]) > math.radians(SPREAD_DEG)
                             for k in chosen):  # fmt: skip
            chosen.append(int(j))
    if not chosen:
        return []
    heights = np.maximum(floor.distance(p), 0.0)  # a cluster stands on the floor
    toward = np.asarray(viewpoint, dtype=np.float64) - p.mean(0)
    sight = np.array([toward @ a, toward @ b])
    sight /= max(float(np.linalg.norm(sight)), 1e-9)
    centred = flat - flat.mean(0)
    axes = np.linalg.svd(centred, full_matrices=False)[2]
    ends = percentiles(centred @ axes.T, [2, 98])  # (2, 2): along its two axes
    whole = [np.log(float(percentiles(heights, [98])[0]) + 0.02), *np.log(ends[1] - ends[0] + 0.02)]
    cuts = []
    for rank, j in enumerate(chosen):
        i, offset = int(where[j]), offsets[j]
        empty = _empty_run(hist[j], i, max(1.0, 0.002 * n)) * BIN_M
        features = cut_features(
            flat, heights, along[:, j], offset, directions[j], sight,
            [best[j], strip[j, i] / n, empty, lesser[j, i] / n, len(full)], whole, rank,
            best[chosen[0]],
        )  # fmt: skip
        normal = directions[j, 0] * a + directions[j, 1] * b
        cuts.append(Cut(normal, float(offset), features))
    return cuts


def cut_features(
    flat: NDArray, heights: NDArray, along: NDArray, offset: float, direction: NDArray,
    sight: NDArray, strip: list[float], whole: list[float], rank: int, best_score: float,
) -> NDArray[np.float64]:  # fmt: skip
    """One cut's features (22,), from the cluster's points on the floor (n, 2), their heights
    (n,) and places along the cut's direction (n,) (2,), the camera's direction along the floor
    (2,), the strip's [score, share of points in it, empty width (m), lesser side's share, the
    cluster's points] and the whole cluster's [top, footprint's two extents] (logs): the strip's
    measures (logs); the two parts' (larger first) tops, bases, extents across the cut and along
    it (logs); how square the cut stands to the line of sight; the whole's measures; the cut's
    rank among the candidates; the share of the heights near the cut that the strip crosses;
    its score over the best candidate's (log); how square each part's long axis stands to the
    cut."""
    score, in_strip, empty, side, count = strip
    first = along < offset
    parts = sorted([first, ~first], key=lambda m: -int(m.sum()))
    across = flat @ np.array([-direction[1], direction[0]])
    out = [np.log(score + 1e-4), np.log(in_strip + 1e-4), np.log(empty + 0.005), side,
           np.log(count)]  # fmt: skip
    ends = [percentiles(np.stack([heights[m], along[m], across[m]]), [2, 98], axis=1)
            for m in parts]  # (2, 3) each: 2nd and 98th percentiles  # fmt: skip
    out += [np.log(e[1, 0] + 0.02) for e in ends]  # tops
    out += [np.log(e[0, 0] + 0.02) for e in ends]  # bases
    out += [np.log(e[1, 1] - e[0, 1] + 0.02) for e in ends]  # extents across the cut
    out += [np.log(e[1, 2] - e[0, 2] + 0.02) for e in ends]  # and along it
    out += [abs(float(direction @ sight)), *whole, float(rank)]
    near, crossed = np.abs(along - offset) < 0.06, np.abs(along - offset) < 0.015
    levels = np.floor(heights / 0.05).astype(np.int64)
    out.append(len(np.unique(levels[crossed])) / max(1, len(np.unique(levels[near]))))
    out.append(np.log(score + 1e-4) - np.log(best_score + 1e-4))
    for m in parts:
        part = flat[m] - flat[m].mean(0)
        out.append(abs(float(np.linalg.svd(part, full_matrices=False)[2][0] @ direction)))
    return np.asarray(out, dtype=np.float64)


def _apart(a: float, b: float) -> float:
    """The angle (radians) between two lines along the floor at angles a and b."""
    d = abs(a - b) % math.pi
    return min(d, math.pi - d)


def _empty_run(hist: NDArray, at: int, most: float) -> int:
    """How many bins about ``at`` of a histogram (W,) hold at most ``most`` points (0 where
    ``at`` itself holds more)."""
    if hist[at] > most:
        return 0
    lo = hi = at
    while lo > 0 and hist[lo - 1] <= most:
        lo -= 1
    while hi < len(hist) - 1 and hist[hi + 1] <= most:
        hi += 1
    return hi - lo + 1


@dataclass(frozen=True)
class CutJudge:
    """Cuts' features (K, F) -> the probability that each parts two objects, by ``network``
    (classes ``CLASSES``); a cut is made from ``threshold`` on. ``fit``: how it was fitted."""

    network: FeatureNetwork
    threshold: float
    fit: dict[str, Any]

    def probabilities(self, features: ArrayLike) -> NDArray[np.float64]:
        """features (K, F) -> (K,)."""
        return self.network.probabilities(features)[..., CLASSES.index("two")]

    def to_dict(self) -> dict[str, Any]:
        return {"classes": list(CLASSES), "threshold": self.threshold,
                **self.network.to_dict(), "fit": self.fit}  # fmt: skip

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CutJudge:
        if tuple(d.get("classes", ())) != CLASSES:
            raise ValueError(f"a cut judge's classes are {CLASSES}, got {d.get('classes')}")
        return cls(FeatureNetwork.from_dict(d), float(d["threshold"]), d.get("fit", {}))


@lru_cache(maxsize=4)
def load_cut_judge(path: Path = FILE) -> CutJudge | None:
    """The cut judge at ``path`` (None where there is no file)."""
    if not path.exists():
        return None
    return CutJudge.from_dict(json.loads(path.read_text()))


def split_touching(
    points: NDArray, objects: list[NDArray[np.int64]], floor: Plane, judge: CutJudge,
    viewpoint: NDArray = ORIGIN,
) -> list[NDArray[np.int64]]:  # fmt: skip
    """Clusters (indices into points (N, 3)) standing on ``floor`` -> the same, each cut where
    ``judge`` finds it holds two objects (see the module)."""
    out: list[NDArray[np.int64]] = []
    for rows in objects:
        out += _cut(points, rows, floor, judge, viewpoint, CUTS_DEEP)
    return out


def _cut(
    points: NDArray, rows: NDArray[np.int64], floor: Plane, judge: CutJudge, viewpoint: NDArray,
    deep: int,
) -> list[NDArray[np.int64]]:  # fmt: skip
    if deep == 0 or len(rows) < MIN_POINTS:
        return [rows]
    cuts = cut_candidates(points[rows], floor, viewpoint)
    if not cuts:
        return [rows]
    chance = np.nan_to_num(judge.probabilities(np.stack([c.features for c in cuts])), nan=0.0)
    k = int(np.argmax(chance))
    if chance[k] < judge.threshold:
        return [rows]
    side = cuts[k].side(points[rows])
    return (_cut(points, rows[side], floor, judge, viewpoint, deep - 1)
            + _cut(points, rows[~side], floor, judge, viewpoint, deep - 1))  # fmt: skip


__all__ = [
    "CLASSES",
    "FILE",
    "Cut",
    "CutJudge",
    "cut_candidates",
    "cut_features",
    "load_cut_judge",
    "split_touching",
]
