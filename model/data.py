"""Training and evaluation data: canonical shape sets, random scan batches, fixed scan sets.

* Shapes are loaded once, orientation-checked (``shapes.check_yaw``) and cached as .npz.
* Training batches are fresh random scans every step (a seeded generator per step, so a resumed
  run sees the same data).
* Validation and test scans are fixed (seeded) and cached, in random units (scale 0.01-100), so
  evaluation also checks that the unit does not matter.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.atomic_write import written_whole
from itnet.geometry import apply_rigid, axis_angle_to_matrix, invert_rigid
from itnet.model.scanner import ScanConfig, scan_of
from itnet.model.shapes import (
    Shape,
    check_yaw,
    list_shape_files,
    load_shape,
    random_stretch,
    stretched,
)
from itnet.preprocess import estimate_normalization, pose_to_normalized, resample
from itnet.upright import UP, levelled, rotation_onto, sensed_ups


def save_npz(path: Path, **arrays: object) -> None:
    """np.savez_compressed, written whole (``written_whole``): processes that fill one cache at
    once (parallel training jobs) never read another's half-written file."""
    with written_whole(path) as partial, open(partial, "wb") as out:
        np.savez_compressed(out, **arrays)


@dataclass
class ScanSet:
    """Fixed scans: clouds[i] (K_i, 3) in input units, poses (S, 4, 4) T_canonical_from_input,
    radii (S,) object radius in input units, names (S,)."""

    clouds: list[NDArray[np.float64]]
    poses: NDArray[np.float64]
    radii: NDArray[np.float64]
    names: list[str]

    def save(self, path: Path) -> None:
        sizes = np.array([len(c) for c in self.clouds])
        save_npz(
            path,
            points=np.concatenate(self.clouds),
            sizes=sizes,
            poses=self.poses,
            radii=self.radii,
            names=np.array(self.names),
        )

    @classmethod
    def load(cls, path: Path) -> ScanSet:
        z = np.load(path)
        clouds = np.split(z["points"], np.cumsum(z["sizes"])[:-1])
        return cls(clouds, z["poses"], z["radii"], [str(n) for n in z["names"]])


def _cache_key(*parts: object) -> str:
    return hashlib.sha1(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:12]


def split_files(
    data: Path, category: str, validation_fraction: float, seed: int
) -> dict[str, list[Path]]:
    """Files for train / val / test. Uses DATA/CATEGORY/{train,test} or DATA/{train,test} when
    present (ModelNet's layout), otherwise splits DATA's files 80/20 by a seeded permutation.
    Validation is carved out of train, never out of test. ModelNet's layout may have an empty
    ``test`` folder (a training-only copy of the data)."""
    root = data / category if (data / category).is_dir() else data
    if (root / "train").is_dir() and (root / "test").is_dir():
        train, test = list_shape_files(root / "train"), list_shape_files(root / "test")
        if not train:
            raise ValueError(f"{root}: no training shapes in {root / 'train'}")
    else:
        files = list_shape_files(root)
        order = np.random.default_rng(seed).permutation(len(files))
        cut = int(round(0.8 * len(files)))
        train, test = [files[i] for i in order[:cut]], [files[i] for i in sorted(order[cut:])]
        if not train or not test:
            raise ValueError(f"{root}: found {len(train)} training and {len(test)} test shapes")
    order = np.random.default_rng(seed + 1).permutation(len(train))
    n_val = max(1, int(round(validation_fraction * len(train))))
    val = [train[i] for i in sorted(order[:n_val])]
    train = [train[i] for i in sorted(order[n_val:])]
    return {"train": train, "val": val, "test": test}


ORIENTATION_RULE = 2  # shapes.check_yaw's rule; part of the cache key of checked shapes


def load_shapes(
    files: list[Path],
    frame: str,
    cache: Path,
    check_orientation: bool,
    quarter_turns: int = 0,
    symmetry: str = "none",
) -> tuple[list[Shape], dict]:
    """Canonical shapes for files (cached), turned by the category's ``quarter_turns`` and
    orientation-checked under its ``symmetry``. Returns (shapes, orientation-check counts)."""
    key = _cache_key([str(f) for f in files], frame, check_orientation, quarter_turns % 4, symmetry)
    key = _cache_key(key, ORIENTATION_RULE)
    path = cache / f"shapes-{key}.npz"
    if path.exists():
        z = np.load(path, allow_pickle=False)
        report = json.loads(str(z["report"]))
        shapes = [
            Shape(str(n), p, t if t.size else None)
            for n, p, t in zip(
                z["names"], np.split(z["points"], z["cuts"]), np.split(z["tris"], z["tcuts"])
            )
        ]
        return shapes, report
    shapes = [load_shape(f, frame, quarter_turns) for f in files]
    report = {"loaded": len(shapes)}
    if check_orientation:
        shapes, counts = check_yaw(shapes, symmetry=symmetry)
        report.update(counts)
    if not shapes:  # nothing to cache; the caller says what to do about it
        return shapes, report
    cache.mkdir(parents=True, exist_ok=True)
    tris = [s.triangles if s.triangles is not None else np.zeros((0, 3), np.int64) for s in shapes]
    save_npz(
        path,
        names=np.array([s.name for s in shapes]),
        points=np.concatenate([s.points for s in shapes]),
        cuts=np.cumsum([len(s.points) for s in shapes])[:-1],
        tris=np.concatenate(tris),
        tcuts=np.cumsum([len(t) for t in tris])[:-1],
        report=json.dumps(report),
    )
    return shapes, report


def _pick(configs: list[ScanConfig], rng: np.random.Generator) -> ScanConfig:
    """One of ``configs``, uniformly (no draw when there is one: single-config data unchanged)."""
    return configs[int(rng.integers(len(configs)))] if len(configs) > 1 else configs[0]


def make_scan_set(
    shapes: list[Shape], views: int, seed: int, config: ScanConfig | list[ScanConfig]
) -> ScanSet:
    """``views`` seeded random scans of every shape, each in a random unit (scale 1e-2..1e2).
    A list of configs: each scan uses one, drawn uniformly."""
    rng = np.random.default_rng(seed)
    configs = config if isinstance(config, list) else [config]
    clouds, poses, radii, names = [], [], [], []
    for shape in shapes:
        for _ in range(views):
            cloud, pose = scan_of(shape, rng, _pick(configs, rng))
            unit = 10 ** rng.uniform(-2, 2)
            pose = pose.copy()
            pose[:3, 3] *= unit
            clouds.append(cloud * unit)
            poses.append(pose)
            radii.append(unit)
            names.append(shape.name)
    return ScanSet(clouds, np.array(poses), np.array(radii), names)


def cached_scan_set(
    shapes: list[Shape], views: int, seed: int, config: ScanConfig, cache: Path
) -> ScanSet:
    # the names and a fingerprint of the geometry (a category's turn changes the points, not names)
    fingerprint = round(float(sum(np.abs(s.points[:4] @ [1.0, 2.0, 3.0]).sum() for s in shapes)), 6)
    viewpoints = [] if config.elevation is None else [list(config.elevation)]  # not in its repr
    if config.cut_below is not None:  # nor this
        viewpoints.append(["cut_below", *config.cut_below])
    if config.sensor != "clean":  # the camera's parameters, not only its name
        from itnet.model.sensor import SENSORS

        viewpoints.append(repr(SENSORS[config.sensor]))
    if config.surroundings is not None:  # nor this
        viewpoints.append(repr(config.surroundings))
    key = _cache_key([s.name for s in shapes], views, seed, config, fingerprint, *viewpoints)
    path = cache / f"scans-{key}.npz"
    if path.exists():
        return ScanSet.load(path)
    scans = make_scan_set(shapes, views, seed, config)
    cache.mkdir(parents=True, exist_ok=True)
    scans.save(path)
    return scans


def _normalised_example(
    cloud: NDArray, pose: NDArray, points: int, rng: np.random.Generator
) -> tuple[NDArray, NDArray]:
    """One scan -> (normalised resampled points (points, 3), target pose in the normalised frame),
    normalised exactly as the runtime does it."""
    norm = estimate_normalization(cloud)
    return resample(norm.apply(cloud), points, rng), pose_to_normalized(pose, norm)


def training_batch(
    shapes: list[Shape],
    batch: int,
    points: int,
    rng: np.random.Generator,
    config: ScanConfig | list[ScanConfig],
    indices: NDArray[np.int64] | None = None,
    stretch: float = 1.0,
    upright: float | None = None,
    near: NearStarts | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Fresh random scans -> (normalised points (B, points, 3), target poses (B, 4, 4)). A list
    of configs: each scan uses one, drawn uniformly. ``indices`` (B,): the shapes to scan (by
    default drawn uniformly). ``stretch`` > 1: each shape is first stretched along its canonical
    axes by factors drawn log-uniformly in [1/stretch, stretch] (``shapes.stretched``; the pose
    is unchanged). ``upright`` (degrees): each scan levelled by its up direction as a caller's
    gravity sensor gives it, the truth tilted by an error drawn uniformly in [0, upright]
    (:func:`upright_scan`): what a run held upright starts from. ``near``: that share of the
    scans starts near its answer instead (:func:`near_start`), as a run's last iterations do."""
    configs = config if isinstance(config, list) else [config]
    xs, targets = np.empty((batch, points, 3), np.float32), np.empty((batch, 4, 4), np.float32)
    if indices is None:
        indices = rng.integers(len(shapes), size=batch)
    for b, i in enumerate(indices):
        shape, config = shapes[i], _pick(configs, rng)
        if stretch > 1:
            if config.splat > 0 and shape.triangles is None:
                shape.discs()  # computed once on the original, carried over to every stretch
            shape = stretched(shape, random_stretch(rng, stretch))
        cloud, pose = scan_of(shape, rng, config)
        if upright is not None:
            cloud, pose = upright_scan(cloud, pose, rng.uniform(0.0, upright), rng)
        x, target = _normalised_example(cloud, pose, points, rng)
        if near is not None and rng.random() < near.share:
            x, target = near_start(x, target, rng, near.max_deg, near.max_shift)
        xs[b], targets[b] = x, target
    return xs, targets


@dataclass(frozen=True)
class NearStarts:
    """Training scans that start near their answer: ``share`` of them, each moved to within
    ``max_deg`` degrees and ``max_shift`` (normalised units: the scan's RMS radius) of it."""

    share: float
    max_deg: float = 20.0
    max_shift: float = 0.2


def near_start(
    points: NDArray, target: NDArray, rng: np.random.Generator, max_deg: float, max_shift: float
) -> tuple[NDArray, NDArray]:
    """A normalised scan (N, 3) and its target T (4, 4) -> the scan as a run sees it once it is
    nearly right, and that scan's target: the canonical points T x moved by a small random
    rigid error E (angle uniform in [0, max_deg] about a uniform axis, a shift of length uniform
    in [0, max_shift] in a uniform direction), x' = E T x, whose target is E^-1. What the
    network sees in its last iterations, where precision is decided."""
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    error = np.eye(4)
    error[:3, :3] = axis_angle_to_matrix(axis, np.radians(rng.uniform(0.0, max_deg)))
    error[:3, 3] = direction / np.linalg.norm(direction) * rng.uniform(0.0, max_shift)
    moved = apply_rigid(error @ target, points)
    return moved.astype(points.dtype), invert_rigid(error).astype(target.dtype)


def upright_scan(
    cloud: NDArray, pose: NDArray, error_deg: float, rng: np.random.Generator
) -> tuple[NDArray, NDArray]:
    """A scan (N, 3) and its pose T_canonical_from_input (4, 4) -> the scan levelled about its
    origin by its up direction tilted ``error_deg`` from the truth (``itnet.upright``), and the
    pose of the levelled scan: the object stands, up to the error, and keeps its yaw."""
    up = sensed_ups(pose[None], error_deg, rng)[0]
    stand = rotation_onto(up, UP)
    moved = pose.copy()
    moved[:3, :3] = pose[:3, :3] @ stand.T
    return levelled(cloud, up).astype(cloud.dtype), moved
