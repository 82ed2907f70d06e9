"""A scene object's centre along the floor, finished by its pose model's scene correction.

In a scene the camera sees furniture from 2-4 m and near its horizon: one side and the top. The
pose model's own centre corrections (``itnet.centre``) were fitted on views of single objects;
on the validation scenes the objects whose rotation was right still had their centre 0.037 r
nearer the camera than the truth on average, and a centre off by more than 0.1 r was the
largest kind of pose miss. The same linear map (``itnet.centre``: statistics of the object's
points moved into its estimated canonical frame and the direction toward the camera), fitted
per pose model on scenes of *training* shapes (``itnet fit scene-centre``),
predicts where the centre lies. Only its move along the floor is kept: the floor already says
how high the centre is (``pipeline.floor_centred``).

The table (``centre_along_floor.json``) names each pose model's graph by its SHA-256: a model it
was not fitted for (another model folder, a model trained again) gets no correction.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.centre import FEATURES_VIEWPOINT, CentreCorrection, centre_features, sensor_direction
from itnet.geometry import apply_rigid
from itnet.graph_digest import graph_digest
from itnet.preprocess import (
    Normalization,
    cap_points,
    estimate_normalization,
    pose_from_normalized,
    pose_to_normalized,
)

TABLE = Path(__file__).with_name("centre_along_floor.json")
MAX_POINTS = 2048  # an object's points the features are measured on (a fixed draw beyond it)


@dataclass(frozen=True)
class MovedObject:
    """An object's points in its estimated canonical frame, normalised (M, 3), the
    normalisation, the pose in the normalised frame (4, 4), and the features (F,) of the points
    and the camera's direction."""

    moved: NDArray
    normalization: Normalization
    pose_normalized: NDArray
    features: NDArray[np.float64]


def moved_object(points: NDArray, pose: NDArray, viewpoint: NDArray) -> MovedObject:
    """An object's points (K, 3) and pose T_canonical_from_input (4, 4), in the camera's frame,
    and the camera's position (3,) -> the object moved where its pose puts it (normalised) and
    its features (``itnet.centre.centre_features`` with the direction toward the camera)."""
    p = cap_points(np.asarray(points, dtype=np.float64), MAX_POINTS, np.random.default_rng(0))
    norm = estimate_normalization(p)
    pose_n = pose_to_normalized(pose, norm)
    moved = apply_rigid(pose_n, norm.apply(p).astype(np.float64))
    toward = sensor_direction(pose_n, (np.asarray(viewpoint, dtype=np.float64) - norm.center)
                              / norm.scale)  # fmt: skip
    return MovedObject(moved, norm, pose_n, centre_features(moved, toward))


def true_offset(seen: MovedObject, truth: NDArray) -> NDArray[np.float64]:
    """Where the true object centre (of T_canonical_from_input ``truth`` (4, 4)) lies in the
    moved, normalised frame (3,): what the correction learns to predict."""
    centre = -truth[:3, :3].T @ truth[:3, 3]
    norm = seen.normalization
    return apply_rigid(seen.pose_normalized, ((centre - norm.center) / norm.scale)[None])[0]


def centred_along_floor(
    points: NDArray, pose: NDArray, correction: CentreCorrection, viewpoint: NDArray,
    up: NDArray,
) -> NDArray[np.float64]:  # fmt: skip
    """An object's points (K, 3) and pose (4, 4) in the camera's frame, its scene correction,
    the camera's position (3,) and the floor's unit normal (3,) -> the pose with the object's
    centre moved along the floor to where the correction predicts it (its height unchanged).
    ValueError where the pose puts the camera on the object's centre (no direction to it)."""
    seen = moved_object(points, pose, viewpoint)
    finished = seen.pose_normalized.copy()
    finished[:3, 3] -= correction.predict(seen.features)
    rotation = np.asarray(pose, dtype=np.float64)[:3, :3]
    before = -rotation.T @ np.asarray(pose, dtype=np.float64)[:3, 3]
    after = -rotation.T @ pose_from_normalized(finished, seen.normalization)[:3, 3]
    move = after - before
    move -= float(move @ up) * np.asarray(up, dtype=np.float64)
    out = np.array(pose, dtype=np.float64)
    out[:3, 3] = -rotation @ (before + move)
    return out


@dataclass(frozen=True)
class CentreTable:
    """Each pose model's scene correction: model name -> (its graph's SHA-256, card left out:
    ``itnet.graph_digest``; correction)."""

    corrections: dict[str, tuple[str, CentreCorrection]]

    def for_model(self, name: str, path: Path) -> CentreCorrection | None:
        """The correction fitted for this model's graph, or None (none fitted, or fitted for
        another graph of that name)."""
        entry = self.corrections.get(name)
        if entry is None or entry[0] != graph_digest(path):
            return None
        return entry[1]

    def to_dict(self) -> dict:
        return {name: {"graph_sha256": digest, "correction": correction.to_dict()}
                for name, (digest, correction) in sorted(self.corrections.items())}  # fmt: skip

    @classmethod
    def from_dict(cls, data: dict) -> CentreTable:
        corrections = {}
        for name, entry in data.items():
            correction = CentreCorrection.from_dict(entry["correction"])
            if correction.features != FEATURES_VIEWPOINT:
                raise ValueError(f"{name}: a scene correction takes the camera's direction")
            corrections[name] = (str(entry["graph_sha256"]), correction)
        return cls(corrections)


@lru_cache(maxsize=4)
def load_table(path: Path = TABLE) -> CentreTable:
    """The table at ``path`` (an empty one where there is no file)."""
    if not path.exists():
        return CentreTable({})
    return CentreTable.from_dict(json.loads(path.read_text()))
