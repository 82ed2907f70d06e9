"""Finishing a pose's object centre by a per-category linear correction (pure numpy).

IT-Net finds the rotation and then the centre of an object of which it sees one side, and it
places the centre systematically too near the visible surface: on the chair's validation views
the estimated centre lies 0.02 r nearer the camera than the truth on average, and by 0.11 r for
the scans whose rotation is right and centre wrong (5% of paper views, 8% of occluded views:
the largest single kind of miss, docs/models.md *How a pose is finished*). Where the cloud lies in
the estimated canonical frame says a lot about which side was seen, so a linear map from a
few statistics of the moved cloud to the true centre's offset, fitted by ridge regression on
scans of training shapes posed by the served model (``itnet.model.centre_fit``), moves the
centre most of the way back.

Everything is in the normalised frame of the run (the cloud centred on its centroid and divided
by its RMS radius), so the correction is unit-free: the features of the moved cloud ``R x + t``
(N, 3) are its per-axis quantiles, mean, extremes and a coarse occupancy grid; the prediction is
where the object's centre lies in that frame, and the finished pose moves it to the origin.

Where the caller knows where the sensor was (a depth camera's cloud in its own frame has it at
the origin), a second map (``FEATURES_VIEWPOINT``) also takes the direction from the estimated
centre toward the sensor, in the moved frame: the centre's error lies mostly along that ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from itnet.columns import percentiles
from itnet.geometry import apply_rigid

FEATURES = "quantiles-extremes-grid4-v1"
QUANTILES = (5.0, 25.0, 50.0, 75.0, 95.0)
GRID = 4  # cells a side of the occupancy grid
GRID_HALF_WIDTH = 2.0  # the grid spans [-2, 2]^3 RMS radii
FEATURE_COUNT = 3 * len(QUANTILES) + 9 + GRID**3
FEATURES_VIEWPOINT = "quantiles-extremes-grid4-viewpoint-v1"  # FEATURES + the sensor's direction
FEATURE_COUNTS = {FEATURES: FEATURE_COUNT, FEATURES_VIEWPOINT: FEATURE_COUNT + 3}


def centre_features(moved: NDArray, toward: NDArray | None = None) -> NDArray[np.float64]:
    """A moved, normalised cloud (N, 3) -> its features (FEATURE_COUNT,): per-axis quantiles (15),
    mean (3), minimum (3), maximum (3), and the share of points in each cell of a 4x4x4 grid
    over [-2, 2]^3 (64; points outside fall in the border cells); with ``toward`` (3,), the unit
    direction toward the sensor in the moved frame, those and it (FEATURE_COUNT + 3,)."""
    p = np.asarray(moved, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"expected a non-empty (N, 3) cloud, got shape {p.shape}")
    quantiles = percentiles(p, list(QUANTILES), axis=0).ravel()
    cell = np.floor((p + GRID_HALF_WIDTH) / (2 * GRID_HALF_WIDTH / GRID)).astype(np.int64)
    cell = np.clip(cell, 0, GRID - 1)
    flat = (cell[:, 0] * GRID + cell[:, 1]) * GRID + cell[:, 2]
    grid = np.bincount(flat, minlength=GRID**3) / len(p)
    extra = [] if toward is None else [np.asarray(toward, dtype=np.float64).reshape(3)]
    return np.concatenate([quantiles, p.mean(0), p.min(0), p.max(0), grid, *extra])


def sensor_direction(pose: NDArray, viewpoint: NDArray) -> NDArray[np.float64]:
    """The unit direction (3,) from the estimated object centre (the moved frame's origin) toward
    the sensor at ``viewpoint`` (3,, normalised input frame), for a pose (4, 4)."""
    where = apply_rigid(np.asarray(pose, dtype=np.float64), np.reshape(viewpoint, (1, 3)))[0]
    norm = float(np.linalg.norm(where))
    if not np.isfinite(norm) or norm < 1e-9:
        raise ValueError("the viewpoint lies on the object's estimated centre")
    return where / norm


@dataclass(frozen=True)
class CentreCorrection:
    """A linear map from standardised features to the object centre's offset (normalised units).

    mean, scale: (F,) standardisation; weights: (F + 1, 3), the last row the intercept."""

    mean: NDArray[np.float64]
    scale: NDArray[np.float64]
    weights: NDArray[np.float64]
    features: str = FEATURES

    def __post_init__(self) -> None:
        if self.features not in FEATURE_COUNTS:
            known = ", ".join(FEATURE_COUNTS)
            raise ValueError(f"unknown centre features {self.features!r} (known: {known})")
        f = FEATURE_COUNTS[self.features]
        shapes = (np.shape(self.mean), np.shape(self.scale), np.shape(self.weights))
        if shapes != ((f,), (f,), (f + 1, 3)):
            raise ValueError(
                f"centre correction shapes {shapes}, expected ({f},), ({f},), ({f + 1}, 3)"
            )
        if not (np.all(np.isfinite(self.weights)) and np.all(np.asarray(self.scale) > 0)):
            raise ValueError("centre correction: weights must be finite and scales positive")

    @property
    def uses_viewpoint(self) -> bool:
        return self.features == FEATURES_VIEWPOINT

    def predict(self, features: NDArray) -> NDArray[np.float64]:
        """Features (..., F) -> where the object's centre lies in each moved cloud's frame
        (..., 3), normalised units."""
        z = (np.asarray(features, dtype=np.float64) - self.mean) / self.scale
        return z @ self.weights[:-1] + self.weights[-1]

    def offset(self, moved: NDArray, toward: NDArray | None = None) -> NDArray[np.float64]:
        """Where the object's centre lies in the moved cloud's frame (3,), normalised units;
        ``toward`` (the sensor's direction, ``sensor_direction``) for a viewpoint correction."""
        if self.uses_viewpoint != (toward is not None):
            raise ValueError("a viewpoint correction needs the sensor's direction, a plain one not")
        return self.predict(centre_features(moved, toward))

    def to_dict(self) -> dict:
        return {
            "features": self.features,
            "mean": [round(float(v), 6) for v in self.mean],
            "scale": [round(float(v), 6) for v in self.scale],
            "weights": [[round(float(v), 6) for v in row] for row in self.weights],
        }

    @classmethod
    def from_dict(cls, data: dict) -> CentreCorrection:
        return cls(
            mean=np.asarray(data["mean"], dtype=np.float64),
            scale=np.asarray(data["scale"], dtype=np.float64),
            weights=np.asarray(data["weights"], dtype=np.float64),
            features=str(data.get("features", FEATURES)),
        )


def fit_centre_correction(
    features: NDArray, offsets: NDArray, ridge: float = 10.0
) -> CentreCorrection:
    """Ridge regression: features (S, F) of moved clouds, the true centre's offsets (S, 3) in
    their frames -> the correction. ``ridge`` weighs the squared weights (standardised features)."""
    x = np.asarray(features, dtype=np.float64)
    y = np.asarray(offsets, dtype=np.float64)
    by_count = {count: name for name, count in FEATURE_COUNTS.items()}
    if x.ndim != 2 or x.shape[1] not in by_count or y.shape != (len(x), 3) or len(x) < 2:
        raise ValueError(
            f"expected features (S, {FEATURE_COUNT} or {FEATURE_COUNT + 3}) and offsets (S, 3), "
            "S >= 2"
        )
    mean = x.mean(0)
    scale = x.std(0)
    scale[scale < 1e-6] = 1.0  # a constant feature (an empty grid cell) carries nothing
    a = np.concatenate([(x - mean) / scale, np.ones((len(x), 1))], axis=1)
    penalty = ridge * np.eye(a.shape[1])
    penalty[-1, -1] = 0.0  # the intercept is not shrunk
    weights = np.linalg.solve(a.T @ a + penalty, a.T @ y)
    return CentreCorrection(mean=mean, scale=scale, weights=weights, features=by_count[x.shape[1]])


def centre_finished(
    points: NDArray,
    pose: NDArray,
    correction: CentreCorrection,
    viewpoint: NDArray | None = None,
) -> NDArray[np.float64]:
    """The pose (4, 4) of a normalised cloud (N, 3), its translation moved so that the centre
    the correction predicts lands on the origin; ``viewpoint`` (3,, normalised input frame): the
    sensor's position, for a viewpoint correction."""
    pose = np.asarray(pose, dtype=np.float64)
    moved = apply_rigid(pose, np.asarray(points, dtype=np.float64))
    toward = None if viewpoint is None else sensor_direction(pose, viewpoint)
    out = pose.copy()
    out[:3, 3] -= correction.offset(moved, toward)
    return out
