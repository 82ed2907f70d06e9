"""Scenes made here, without any dataset: boxes and a box-built chair on a floor before a wall,
rendered by the development scenes' renderer (``model/scenes.py``)."""

from __future__ import annotations

import math

import numpy as np

from itnet.geometry import axis_angle_to_matrix
from itnet.model.scenes import Scene, render, world_from_camera
from itnet.model.shapes import Shape
from itnet.scene import Intrinsics
from itnet.scene.feature_network import FeatureNetwork
from itnet.scene.touching import CLASSES, CutJudge

BoxSpec = tuple[tuple[float, float, float], tuple[float, float, float]]  # centre, size


def boxes_shape(boxes: list[BoxSpec], points: int = 1024, seed: int = 0) -> Shape:
    """Points on the surfaces of boxes (canonical, +y up), centred and scaled to the unit
    sphere as shapes are."""
    rng = np.random.default_rng(seed)
    areas = np.array([2 * (s[0] * s[1] + s[1] * s[2] + s[0] * s[2]) for _, s in boxes])
    counts = rng.multinomial(points, areas / areas.sum())
    out = []
    for (centre, size), n in zip(boxes, counts, strict=True):
        p = rng.uniform(-0.5, 0.5, size=(n, 3))
        axis = rng.integers(0, 3, size=n)
        p[np.arange(n), axis] = rng.choice([-0.5, 0.5], size=n)  # onto a face
        out.append(p * size + centre)
    p = np.concatenate(out)
    p -= (p.min(0) + p.max(0)) / 2
    return Shape("boxes", p / np.linalg.norm(p, axis=1).max())


def chair_shape() -> Shape:
    """A chair of boxes: a seat, a back on +z, four legs."""
    legs = [((x, 0.22, z), (0.05, 0.44, 0.05)) for x in (-0.2, 0.2) for z in (-0.2, 0.2)]
    return boxes_shape([((0, 0.46, 0), (0.46, 0.05, 0.46)), ((0, 0.72, 0.21), (0.46, 0.5, 0.05)),
                        *legs])  # fmt: skip


def make_test_scene(
    objects: list[tuple[Shape, float, float, float, float]],
    width: int = 320,
    height: int = 240,
    camera_height: float = 1.4,
    pitch_deg: float = 15.0,
    seed: int = 0,
    wall_m: float = 6.0,
) -> Scene:
    """Objects (shape, metres per unit, x, z on the floor in metres, yaw in degrees) before a
    wall ``wall_m`` ahead, seen from ``camera_height``, pitched down."""
    intrinsics = Intrinsics.from_fov(width, height, 60.0)
    camera = world_from_camera(camera_height, pitch_deg, 0.0)
    placed = []
    for shape, scale, x, z, yaw in objects:
        world = np.eye(4)
        world[:3, :3] = axis_angle_to_matrix([0.0, 1.0, 0.0], math.radians(yaw))
        world[:3, 3] = [x, -float(shape.points[:, 1].min()) * scale, z]
        placed.append((shape, scale, world))
    wall = (np.array([0.0, 0.0, -1.0]), wall_m)
    depth, labels = render(placed, camera, wall, intrinsics, width, height,
                           np.random.default_rng(seed))  # fmt: skip
    return Scene(depth, intrinsics, labels, [])


FEATURES = 22  # a cut's features (itnet.scene.touching.cut_features)


def sure_judge(answer: str, features: int = FEATURES, threshold: float = 0.8) -> CutJudge:
    """A judge that answers ``answer`` surely, whatever the cut."""
    bias = np.zeros(2)
    bias[CLASSES.index(answer)] = 8.0
    network = FeatureNetwork(np.zeros(features), np.ones(features), np.zeros((features, 2)),
                             np.zeros(2), np.zeros((2, 2)), bias)  # fmt: skip
    return CutJudge(network, threshold, {"note": "sure"})
