"""A scene's answer: each object's category, probability, pose, points and box (typed), and
their JSON form (the CLI's line, the HTTP reply)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from itnet.planes import Plane


@dataclass(frozen=True)
class Box:
    """An oriented box in the camera frame: ``center`` (3,), ``size`` (3,) along its axes,
    ``rotation`` (3, 3) R_camera_from_box (columns: the box's x, y, z axes; y is up)."""

    center: NDArray[np.float64]
    size: NDArray[np.float64]
    rotation: NDArray[np.float64]

    def corners(self) -> NDArray[np.float64]:
        """The 8 corners (8, 3) in the camera frame."""
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        return self.center + (signs * self.size / 2) @ self.rotation.T

    def as_dict(self) -> dict[str, Any]:
        return {
            "center": _rounded(self.center),
            "size": _rounded(self.size),
            "R_camera_from_box": _rounded(self.rotation),
        }


@dataclass
class SceneObject:
    """One object: ``indices`` (K,) of its points in the input (flat pixel indices of a depth
    image, rows of a cloud), its category, and its pose T_canonical_from_input (4, 4) where its
    category has a pose model (else ``pose`` is None and ``no_pose`` says why)."""

    indices: NDArray[np.int64]
    category: str | None  # None: unknown (``unknown`` says why: itnet.scene.unknown)
    probability: float
    candidates: list[dict[str, Any]]
    unsure: bool
    box: Box
    pose: NDArray[np.float64] | None = None
    run: dict[str, Any] | None = None  # the anytime run's reply (iterations, stopped_by, ...)
    no_pose: str | None = None
    named_by: str = "classifier"  # or 'scene_classifier' (itnet.scene.scene_classifier)
    # its base lies below the view: seen from part of its height up (its box still reaches the
    # floor; itnet.scene.pipeline.base_out_of_view)
    base_out_of_view: bool = False
    unknown: str | None = None  # 'not_ours', 'unsure', 'too_large' or 'budget' (not named)

    def as_dict(self, with_indices: bool = True) -> dict[str, Any]:
        """The JSON form: ``category`` (null: unknown), ``category_probability``, ``candidates``,
        ``unsure``, ``named_by``, ``base_out_of_view``, ``unknown`` (why it is unknown: 'not_ours',
        'unsure', 'too_large', or 'budget': the scene's budget left no time to name it; null
        where named), the run's fields (``T_canonical_from_input``, ``quat_wxyz``,
        ``quat_xyzw``, ``translation``, ``iterations``, ``stopped_by``, ``model``, ...; null pose
        where none, with ``no_pose``), ``box``, ``points`` (how many) and ``indices``."""
        out: dict[str, Any] = {
            "category": self.category,
            "category_probability": round(self.probability, 6),
            "candidates": self.candidates,
            "unsure": self.unsure,
            "named_by": self.named_by,
            "base_out_of_view": self.base_out_of_view,
            "unknown": self.unknown,
        }
        if self.run is not None:
            out.update(self.run)
        else:
            out.update({"T_canonical_from_input": None, "no_pose": self.no_pose})
        out["box"] = self.box.as_dict()
        out["points"] = len(self.indices)
        if with_indices:
            out["indices"] = self.indices.tolist()
        return out


@dataclass
class SceneResult:
    """Every object found in a scene (largest first), the floor and up it stands on (None:
    no floor found, no objects), the walls removed, and the times (ms from the request)."""

    objects: list[SceneObject]
    up: NDArray[np.float64] | None
    floor: Plane | None
    walls: list[Plane] = field(default_factory=list)
    points: int = 0
    image_shape: tuple[int, int] | None = None
    budget_ms: float = 0.0
    segment_ms: float = 0.0
    elapsed_ms: float = 0.0
    room: bool = False  # taken for a room's cloud (no camera at its origin; itnet.scene.room)

    def as_dict(self, with_indices: bool = True) -> dict[str, Any]:
        return {
            "objects": [o.as_dict(with_indices) for o in self.objects],
            "up": None if self.up is None else _rounded(self.up),
            "floor": None if self.floor is None else _plane(self.floor),
            "walls": [_plane(w) for w in self.walls],
            "points": self.points,
            "image_shape": None if self.image_shape is None else list(self.image_shape),
            "budget_ms": self.budget_ms,
            "segment_ms": round(self.segment_ms, 3),
            "elapsed_ms": round(self.elapsed_ms, 3),
            "room": self.room,
        }


def _plane(plane: Plane) -> dict[str, Any]:
    return {"normal": _rounded(plane.normal), "offset": round(float(plane.offset), 6)}


def _rounded(values: NDArray) -> list[Any]:
    return np.round(np.asarray(values, dtype=np.float64), 6).tolist()


def scene_row(path: Path | str, result: SceneResult, indices: bool) -> dict[str, Any]:
    """What ``itnet scene --json`` prints for a file (and ``itnet batch scene`` writes):
    ``file`` and the result's JSON form."""
    return {"file": str(path), **result.as_dict(indices)}
