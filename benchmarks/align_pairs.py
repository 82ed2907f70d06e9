"""Pairs of scans of one object for the alignment benchmarks: three generators that differ as
users' pairs do.

    pairs = make_pairs("camera", files, count=100, seed=2024, category="chair")

Each pair is two partial scans of the same held-out ModelNet10 shape (canonical frame, radius 1),
each in its own camera frame, with the true T_b_from_a and each scan's true up.

* ``any_view``: two independent viewpoints from any direction (full SO(3)), the z-buffer rule
  with the scanner's generic noise (``ScanConfig()``);
* ``camera``: what a depth camera above the floor sees: cameras 5-40 degrees above the object's
  horizon, the base partly below the view (``base_hidden``), a Kinect v2's noise, holes and
  flying pixels on a piece of the category's real size, each scan from its own distance (1-6 m,
  so one scan may have many times the other's points);
* ``overlap``: the same object seen by a RealSense D435 from two cameras at one height, the second
  turned about the object's up by 15-180 degrees from the first, so the two views share from
  nearly all to almost none of their surface; ``overlap_of`` measures how much;
* ``paper``: two independent viewpoints from any direction by the IT-Net paper's rule (the
  nearest point of each pixel, no noise): the views on which the networks are surest, so the
  composed poses are a strong prior that a rival must not displace.

``sensor`` puts every generator's scans through one camera's model instead (``kinect_v2``,
``realsense_d435``, ...: ``model.sensor.SENSORS``), the object at its category's real size:
the same view rules as a depth camera would see them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.alignment.hypotheses import relative_pose
from itnet.geometry import invert_rigid, rigid_from_rotation_translation
from itnet.metrics import alignment_errors, is_correct
from itnet.model import categories
from itnet.model.scanner import (
    ScanConfig,
    add_sensor_effects,
    camera_from_canonical_looking_at,
    named_views,
    scan_shape,
    sensed,
    sensor_views,
    zbuffer_scan,
)
from itnet.model.shapes import Shape, load_shape
from itnet.symmetry import symmetry_group

GENERATORS = ("any_view", "camera", "overlap", "paper")
OVERLAP_TURN_DEG = (15.0, 180.0)  # the second camera's turn about the object's up


@dataclass
class Pair:
    """Clouds A (N, 3) and B (M, 3) in their camera frames, the true T_b_from_a, the radius."""

    a: NDArray[np.float64]
    b: NDArray[np.float64]
    truth: NDArray[np.float64]
    radius: float
    name: str
    ups: tuple[NDArray[np.float64], NDArray[np.float64]]  # each scan's true up, in its frame
    generator: str = "any_view"
    # (S, 4, 4) every alignment as right as the truth: inv(T_cb) · S · T_ca for each turn S of
    # the category's symmetry (SPEC.md: accuracy counts the best of the equivalent poses)
    truths: NDArray[np.float64] | None = None

    def errors(self, estimate: NDArray) -> tuple[float, float]:
        """(rotation error, degrees; translation error, radii) of a T_b_from_a (4x4): the
        least over the equivalent truths."""
        truths = self.truths if self.truths is not None else self.truth[None]
        rot, shift = alignment_errors(estimate[None], truths, self.a.mean(0), self.radius)
        best = int(np.argmin(np.maximum(rot / 10.0, shift / 0.1)))
        return float(rot[best]), float(shift[best])

    def right(self, estimate: NDArray) -> bool:
        """Whether a T_b_from_a (4x4) aligns the pair (10 degrees, 0.1 radii; any equivalent)."""
        rot, shift = self.errors(estimate)
        return bool(is_correct(np.array([rot]), np.array([shift]))[0])


def overlap_of(pair: Pair, distance: float = 0.05) -> float:
    """The share of A's points with a point of B within ``distance`` radii once A is moved by
    the true T_b_from_a: how much of the object the two scans share."""
    from scipy.spatial import cKDTree

    moved = pair.a @ pair.truth[:3, :3].T + pair.truth[:3, 3]
    near = cKDTree(pair.b).query(moved, distance_upper_bound=distance * pair.radius)[0]
    return float(np.isfinite(near).mean())


def _scan_from(shape: Shape, camera_from_canonical: NDArray, rng: np.random.Generator,
               config: ScanConfig) -> NDArray[np.float64]:  # fmt: skip
    """The z-buffer scan of ``shape`` from a given camera (radius-1 units), through the camera
    model of ``config`` (its real size drawn per scan)."""
    seen = zbuffer_scan(shape.points, camera_from_canonical, rng.uniform(*config.pixel),
                        config.tolerance, config.occlusion_tolerance)  # fmt: skip
    if config.sensor != "clean" and len(seen) >= config.min_points:
        seen = sensed(seen, rng, config, rng.uniform(*config.radius_m))
    return add_sensor_effects(seen, rng, config)


def _turned_views(shape: Shape, rng: np.random.Generator, config: ScanConfig,
                  ) -> tuple[NDArray, NDArray, NDArray, NDArray]:  # fmt: skip
    """Two scans from one height, the second camera turned about the object's up: (a, pose_a,
    b, pose_b), the poses T_canonical_from_camera."""
    for _ in range(20):
        elevation = np.radians(rng.uniform(5.0, 40.0))
        azimuth = rng.uniform(-np.pi, np.pi)
        turn = np.radians(rng.uniform(*OVERLAP_TURN_DEG)) * rng.choice([-1.0, 1.0])
        scans = []
        for az in (azimuth, azimuth + turn):
            rotation = camera_from_canonical_looking_at(elevation, az, rng.uniform(-0.2, 0.2))
            centre = np.array([0.0, 0.0, rng.uniform(*config.distance)])
            camera = rigid_from_rotation_translation(rotation, centre)
            scans.append((_scan_from(shape, camera, rng, config), invert_rigid(camera)))
        if min(len(s) for s, _ in scans) >= config.min_points:
            return scans[0][0], scans[0][1], scans[1][0], scans[1][1]
    raise ValueError(f"no pair of views saw enough of {shape.name}")


def generator_config(generator: str, category: str, sensor: str | None = None) -> ScanConfig:
    """The scanner's settings of a generator's scans; ``sensor`` (``model.sensor.SENSORS``):
    every scan by that camera instead, the object at its category's real size (``camera``
    and ``overlap`` have their own camera: a Kinect v2 and a D435)."""
    if generator == "any_view":
        config = ScanConfig()
    elif generator == "camera":
        config = named_views("base_hidden+kinect_v2", category)
    elif generator == "overlap":
        config = replace(named_views("occluded+realsense_d435", category), distance=(2.0, 3.5))
    elif generator == "paper":
        config = named_views("paper", category)
    else:
        raise ValueError(f"unknown pair generator {generator!r} (known: {', '.join(GENERATORS)})")
    if sensor is None:
        return config
    return replace(config, **sensor_views(sensor, categories.real_radius_m(category)))


def make_pairs(generator: str, files: list[Path], count: int, seed: int,
               category: str = "chair", sensor: str | None = None) -> list[Pair]:  # fmt: skip
    """``count`` pairs of ``generator`` cycling over the shape ``files`` (ModelNet frame, turned
    into ``category``'s canonical frame), by ``sensor`` where given (``generator_config``);
    seeded."""
    known = categories.category(category)
    shapes = [load_shape(p, "modelnet", known.quarter_turns) for p in files]
    rng = np.random.default_rng(seed)
    config = generator_config(generator, category, sensor)
    turns = np.tile(np.eye(4), (len(symmetry_group(known.symmetry)), 1, 1))
    turns[:, :3, :3] = symmetry_group(known.symmetry)
    pairs = []
    for i in range(count):
        shape = shapes[i % len(shapes)]
        if generator == "overlap":
            a, pose_a, b, pose_b = _turned_views(shape, rng, config)
        else:
            a, pose_a = scan_shape(shape.points, rng, config)
            b, pose_b = scan_shape(shape.points, rng, config)
        ups = (pose_a[1, :3], pose_b[1, :3])  # R^T e_y: the canonical +y in each camera frame
        truths = relative_pose(turns @ pose_a, pose_b)
        pairs.append(Pair(a, b, truths[0], 1.0, shape.name, ups, generator, truths))
    return pairs


def split_shapes(data: Path, category: str, split: str) -> list[Path]:
    """The shapes of ``split``: ModelNet's test folder, or the validation shapes the category's
    models were trained without (``itnet train``'s split: a tenth of the training folder)."""
    from itnet.model.data import split_files

    return split_files(data, category, 0.1, 0)["val" if split == "validation" else "test"]
