"""Development scenes: ModelNet10 test objects standing on a floor before a wall, seen by a
depth camera, with each object's ground-truth pose.

Never the training shapes: the test split's shapes of each category are cut in two by a seeded
permutation, a validation half (for choosing the segmentation's settings) and a test half
(measured once). A scene holds one to three objects of eight categories (``DEVELOPMENT``; the
desk joins where asked, ``WITH_DESKS``), at real sizes (a chair 0.8-1.0 m tall, a bed 1.9-2.1 m long, ...), each turned by any yaw and
standing on the floor, apart from the others, inside the view; a wall stands behind them.

The camera: 1.1-1.7 m above the floor, pitched down 0-25 degrees (0: level), rolled up to
3 degrees, 60 degrees wide, 320x240 (or any size: the same scene at 640x480 is the same rays,
finer). Depth is rendered per pixel: the floor and the wall exactly (ray-plane), each object's
1,024 points as small oriented discs (``model.surface.surface_discs``), the nearest hit kept;
then depth noise as a structured-light camera has it, ``0.0012 + 0.0019 (z - 0.4)^2`` m, a few
dropped pixels, and millimetre steps. Where asked (``flying_pixels``), a time-of-flight camera's
mixed pixels at depth edges: a share of the pixels whose 4-neighbour lies over 0.1 m behind them
take a depth between the two.

Each object's truth is ``T_canonical_from_input`` for the camera-frame cloud (canonical frame in
metres: the unit-sphere shape scaled by its size), its radius in metres, and the pixels it is
seen at (``labels``: 0 floor or wall, k for the k-th object).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from itnet.geometry import axis_angle_to_matrix, invert_rigid
from itnet.model.categories import MODELNET10
from itnet.model.data import load_shapes, split_files
from itnet.model.distractors import KINDS, distractor, hung
from itnet.model.sensor import SENSORS, mixed_at_edges
from itnet.model.shapes import Shape
from itnet.model.surroundings import ON_TOP_COUNT, on_top_things
from itnet.scene.camera import Intrinsics, depth_to_cloud

# The development scenes' categories (the default), in the order they are drawn: the desk joins
# where asked (make_scene's ``categories``); the monitor stands on a desk, not on the floor.
DEVELOPMENT = ("chair", "table", "toilet", "bed", "bathtub", "sofa", "night_stand", "dresser")
# Each category a scene may hold, in that order: (which extent, its range in metres): 'height'
# or 'length' (the longest horizontal extent): ``Category.scene_size``.
SIZES: dict[str, tuple[str, tuple[float, float]]] = {
    name: size
    for name in (*DEVELOPMENT, "desk")
    if (size := MODELNET10[name].scene_size) is not None
}
WITH_DESKS = (*DEVELOPMENT, "desk")
WIDTH, HEIGHT, FOV_DEG = 320, 240, 60.0
SPLITS = ("validation", "test")
FIT_SPLIT = "train"
HELD_OUT_SPLIT = "held-out"  # the classifiers' validation carve-out of the training split


@dataclass
class SceneObjectTruth:
    category: str
    name: str
    pose: NDArray[np.float64]  # T_canonical_from_input (4, 4), input = the camera frame, metres
    radius: float  # bounding-sphere radius, metres


@dataclass
class Scene:
    """A rendered depth image (H, W) in metres (0: no reading), its intrinsics, the pixels'
    object labels (H, W) (0: none, k: objects[k - 1], then len(objects) + j: others[j - 1]),
    the objects' truths, and the kinds of the things of no category among them (``others``,
    ``model.distractors``)."""

    depth: NDArray[np.float64]
    intrinsics: Intrinsics
    labels: NDArray[np.int64]
    objects: list[SceneObjectTruth]
    others: list[str] = field(default_factory=list)


def split_shapes(
    data: Path, split: str, cache: Path, seed: int = 0, limit: int | None = None
) -> dict[str, list[Shape]]:
    """The ``split`` half ('validation' or 'test') of each category's test shapes, or ('train')
    the pose models' training shapes, or ('held-out') the training split's shapes that the
    classifiers left out of their training (their validation carve-out: 10%, seed 0), both for
    fitting what scenes need, never for measuring; canonical and orientation-checked;
    ``limit``: at most that many a category (a seeded draw)."""
    splits = (*SPLITS, FIT_SPLIT, HELD_OUT_SPLIT)
    if split not in splits:
        raise ValueError(f"split must be one of {splits}, got {split!r}")
    out = {}
    for name in SIZES:
        part = {FIT_SPLIT: "train", HELD_OUT_SPLIT: "val"}.get(split, "test")
        files = split_files(data, name, 0.1, 0)[part]
        order = np.random.default_rng(seed + 17).permutation(len(files))
        if split in (FIT_SPLIT, HELD_OUT_SPLIT):
            half = order
        else:
            half = order[: len(files) // 2] if split == "validation" else order[len(files) // 2 :]
        half = half[:limit]
        cat = MODELNET10[name]
        shapes, _ = load_shapes([files[i] for i in sorted(half)], "modelnet", cache, True,
                                cat.quarter_turns, cat.symmetry)  # fmt: skip
        out[name] = shapes
    return out


def _floor_points(shape: Shape, scale: float, turn: NDArray, where: NDArray) -> NDArray:
    """A placed shape's points on the floor (K, 2): world x and z."""
    return ((shape.points * scale) @ turn.T + where)[:, [0, 2]]


def _against(
    shape: Shape, scale: float, turn: NDArray, floor_y: float,
    placed: list[tuple[Shape, float, NDArray, str, float]], rng: np.random.Generator,
) -> NDArray | None:  # fmt: skip
    """Where (3,) a shape stands against one of the ``placed`` (drawn at random), coming in
    from a random direction until its footprint's points lie 1-5 cm from that one's; None where
    it would then come within 1 cm of another."""
    from scipy.spatial import cKDTree

    anchor_index = int(rng.integers(len(placed)))
    anchor = placed[anchor_index]
    direction = axis_angle_to_matrix([0.0, 1.0, 0.0], rng.uniform(0, 2 * math.pi))[:, 0]
    gap = rng.uniform(0.01, 0.05)
    centre = anchor[2][:3, 3]
    others = [cKDTree(_floor_points(p[0], p[1], p[2][:3, :3], p[2][:3, 3])) for p in placed]
    mine = _floor_points(shape, scale, turn, np.zeros(3))
    reach = anchor[4] + _footprint(shape, scale)
    for step in np.arange(reach + 0.1, 0.0, -0.01):
        where = centre + direction * step
        where[1] = floor_y
        nearest = [float(t.query(mine + where[[0, 2]])[0].min()) for t in others]
        if min(nearest) <= gap:
            if nearest[anchor_index] > gap or min(nearest) < 0.01:
                return None
            return where
    return None


def matched_objects(
    returned: list[NDArray[np.int64]], labels: NDArray[np.int64], count: int, min_iou: float = 0.5
) -> list[tuple[int, int]]:
    """Returned objects' pixel indices (each (K,), flat) against a scene's ``labels`` (H, W) of
    ``count`` objects -> pairs (returned index, scene object's label 1..count) whose intersection
    over union is at least ``min_iou``, best first, each matched once."""
    flat = labels.ravel()
    sizes = np.bincount(flat, minlength=count + 1)
    pairs = []
    for i, indices in enumerate(returned):
        counts = np.bincount(flat[indices], minlength=count + 1)
        for k in range(1, count + 1):
            iou = counts[k] / (len(indices) + sizes[k] - counts[k])
            if iou >= min_iou:
                pairs.append((iou, i, k))
    taken_returned, taken_truth, out = set(), set(), []
    for _, i, k in sorted(pairs, reverse=True):
        if i not in taken_returned and k not in taken_truth:
            taken_returned.add(i)
            taken_truth.add(k)
            out.append((i, k))
    return out


def _size_scale(shape: Shape, category: str, rng: np.random.Generator) -> float:
    """Metres per canonical unit for a real-sized member of the category."""
    which, (lo, hi) = SIZES[category]
    extent = shape.points.max(0) - shape.points.min(0)
    unit = extent[1] if which == "height" else max(extent[0], extent[2])
    return rng.uniform(lo, hi) / unit


def world_from_camera(height: float, pitch_deg: float, roll_deg: float) -> NDArray[np.float64]:
    """T_world_from_camera (4, 4): world +y up, floor y = 0; the camera at ``height`` looking
    along world +z, pitched down and rolled."""
    base = np.diag([-1.0, -1.0, 1.0])  # camera x right, y down, z ahead -> world -x, -y, z
    pitch = axis_angle_to_matrix([1.0, 0.0, 0.0], -math.radians(pitch_deg))
    roll = axis_angle_to_matrix([0.0, 0.0, 1.0], math.radians(roll_deg))
    t = np.eye(4)
    t[:3, :3] = base @ pitch @ roll  # a positive pitch turns the optical axis toward the floor
    t[:3, 3] = [0.0, height, 0.0]
    return t


def _rays(intrinsics: Intrinsics, width: int, height: int) -> NDArray[np.float64]:
    """Each pixel's ray (H, W, 3) in the camera frame, scaled to z = 1 (so a hit's t is its
    depth)."""
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    return np.stack(
        [
            (u - intrinsics.cx) / intrinsics.fx,
            (v - intrinsics.cy) / intrinsics.fy,
            np.ones(u.shape),
        ],
        axis=-1,
    )


def _plane_depth(rays: NDArray, normal: NDArray, offset: float) -> NDArray[np.float64]:
    """Depth (H, W) at which each ray meets the plane ``normal·p + offset = 0`` (camera frame),
    inf where it does not (parallel or behind)."""
    facing = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -offset / facing
    return np.where((np.abs(facing) > 1e-9) & (t > 0), t, np.inf)


def _splat(
    depth: NDArray, labels: NDArray, label: int, centres: NDArray, normals: NDArray,
    radii: NDArray, intrinsics: Intrinsics, max_reach: int = 12,
) -> None:  # fmt: skip
    """Render discs (camera-frame centres (M, 3) with z > 0, unit normals (M, 3), radii (M,))
    into ``depth`` (H, W) where nearer, writing ``label`` into ``labels`` there."""
    h, w = depth.shape
    z = centres[:, 2]
    u = intrinsics.fx * centres[:, 0] / z + intrinsics.cx
    v = intrinsics.fy * centres[:, 1] / z + intrinsics.cy
    reach = np.minimum(np.ceil(radii * intrinsics.fx / z).astype(np.int64), max_reach)
    span = np.arange(-reach.max(), reach.max() + 1)
    du, dv = (o.ravel() for o in np.meshgrid(span, span, indexing="ij"))
    point, k = np.nonzero(
        (np.abs(du)[None] <= reach[:, None]) & (np.abs(dv)[None] <= reach[:, None])
    )
    pu, pv = (
        np.round(u[point]).astype(np.int64) + du[k],
        np.round(v[point]).astype(np.int64) + dv[k],
    )
    inside = (pu >= 0) & (pu < w) & (pv >= 0) & (pv < h)
    point, pu, pv = point[inside], pu[inside], pv[inside]
    rays = np.stack([(pu - intrinsics.cx) / intrinsics.fx, (pv - intrinsics.cy) / intrinsics.fy,
                     np.ones(len(pu))], 1)  # fmt: skip
    n, c = normals[point], centres[point]
    facing = np.einsum("ij,ij->i", n, rays)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", n, c) / facing
    hit = t[:, None] * rays
    ok = (np.abs(facing) > 1e-9) & (t > 0) & (((hit - c) ** 2).sum(1) <= radii[point] ** 2)
    flat = pv[ok] * w + pu[ok]
    t = t[ok]
    nearest = np.full(h * w, np.inf)
    np.minimum.at(nearest, flat, t)
    closer = nearest < depth.ravel()
    depth.ravel()[closer] = nearest[closer]
    labels.ravel()[closer] = label


def render(
    objects: list[tuple[Shape, float, NDArray]], camera: NDArray, wall: tuple[NDArray, float],
    intrinsics: Intrinsics, width: int, height: int, rng: np.random.Generator,
    flying_pixels: float = 0.0, sensor: str | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:  # fmt: skip
    """Objects (shape, metres per unit, T_world_from_canonical (4, 4) of the unit shape's
    rotation and placement), T_world_from_camera (4, 4), the wall (world normal (3,), offset)
    -> (depth (H, W) in metres with sensor effects, labels (H, W)); ``flying_pixels``: the
    share of depth-edge pixels mixed with what lies behind them (``mixed_at_edges``);
    ``sensor``: a named camera's effects (``model.sensor.SENSORS``, drawn from a child of
    ``rng``) instead of the structured-light noise and dropped pixels."""
    camera_from_world = invert_rigid(camera)
    rays = _rays(intrinsics, width, height)
    planes = [(np.array([0.0, 1.0, 0.0]), 0.0), wall]
    depth = np.full((height, width), np.inf)
    for normal, offset in planes:  # into the camera frame: n_c = R^T n, d_c = d + n·t
        n_c = camera[:3, :3].T @ normal
        depth = np.minimum(depth, _plane_depth(rays, n_c, offset + float(normal @ camera[:3, 3])))
    labels = np.zeros((height, width), np.int64)
    for k, (shape, scale, world_from_canonical) in enumerate(objects, start=1):
        normals, spacing = shape.discs()
        t = camera_from_world @ world_from_canonical
        centres = shape.points * scale @ t[:3, :3].T + t[:3, 3]
        _splat(depth, labels, k, centres, normals @ t[:3, :3].T, 1.3 * spacing * scale,
               intrinsics)  # fmt: skip
    seen = np.isfinite(depth)
    if sensor is not None:
        depth[~seen] = 0.0
        focal = (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)
        depth = SENSORS[sensor].apply_to_depth(depth, focal, rng.spawn(1)[0])
        return np.round(depth * 1000) / 1000, labels
    z = depth[seen]
    depth[seen] = z + rng.normal(size=z.shape) * (0.0012 + 0.0019 * (z - 0.4) ** 2)
    depth[~seen] = 0.0
    depth[rng.random(depth.shape) < 0.01] = 0.0
    if flying_pixels > 0:  # drawn from a child of rng: the scenes that follow stay the same
        depth = mixed_at_edges(depth, flying_pixels, rng.spawn(1)[0])
    return np.round(depth * 1000) / 1000, labels


def make_scene(
    shapes: dict[str, list[Shape]], rng: np.random.Generator, width: int = WIDTH,
    height: int = HEIGHT, fov_deg: float = FOV_DEG, touching: bool = False,
    categories: tuple[str, ...] = DEVELOPMENT, pitch_deg: tuple[float, float] = (0.0, 25.0),
    most: int = 3, cut_off: bool = False, flying_pixels: float = 0.0, distractors: int = 0,
    sensor: str | None = None, against_wall: bool = False, on_top: float = 0.0,
) -> Scene:  # fmt: skip
    """One random scene (see the module) of ``categories`` from the given shapes of each, of
    one to ``most`` objects, the camera pitched down by ``pitch_deg`` (low, high; (0, 0): a
    level camera). ``touching``: two to ``most`` objects, each after the first standing against
    one placed before it (its footprint's points 1-5 cm from that one's), as chairs stand at a
    table. ``cut_off``: an object's lower part may lie below the view (a level camera at head
    height sees a chair 2 m away from its seat up); by default each is wholly in view.
    ``flying_pixels``: the share of depth-edge pixels a time-of-flight camera mixes with what
    lies behind them (``mixed_at_edges``; default none). ``distractors``: up to this many things
    of no category (``model.distractors``) stand among the objects, apart from them (drawn from
    a child of ``rng``: the objects, camera and wall are those of the same scene without).
    ``sensor``: the depth as that camera returns it (``model.sensor.SENSORS``: ``kinect_v1``,
    ``kinect_v2``, ``realsense_d435``, ``clean``; ``SensorModel.apply_to_depth``) instead of
    the default structured-light noise. ``against_wall``: the wall stands 0-4 cm behind the
    farthest object (or thing), as furniture stands in a room, with a skirting board and one to
    three pictures or mirrors hung on it (``model.distractors.hung``; drawn from a child of
    ``rng``), which are wall in ``labels``. ``on_top``: the chance that an object carries one to
    three things on its tops (a lamp, books, a vase, a plant, a mirror:
    ``model.surroundings.on_top_things``; drawn from a child of ``rng``), labelled as part of
    their object."""
    layout = _layout(shapes, rng, Intrinsics.from_fov(width, height, fov_deg), width, height,
                     touching, categories, pitch_deg, most, cut_off, distractors, against_wall,
                     on_top)  # fmt: skip
    depth, labels = render(layout.rendered, layout.camera, layout.wall, layout.intrinsics,
                           width, height, rng, flying_pixels, sensor)  # fmt: skip
    labels[labels > layout.counted] = 0  # what hangs on the wall is wall
    truths = [SceneObjectTruth(t.category, t.name, t.pose @ layout.camera, t.radius)
              for t in layout.truths]  # fmt: skip
    return Scene(depth, intrinsics=layout.intrinsics, labels=labels, objects=truths,
                 others=layout.others)  # fmt: skip


def make_room(
    shapes: dict[str, list[Shape]], rng: np.random.Generator, views: int = 3,
    width: int = WIDTH, height: int = HEIGHT, fov_deg: float = FOV_DEG, touching: bool = False,
    categories: tuple[str, ...] = DEVELOPMENT, pitch_deg: tuple[float, float] = (0.0, 25.0),
    most: int = 3, cut_off: bool = False, flying_pixels: float = 0.0, distractors: int = 0,
    sensor: str | None = None, against_wall: bool = False, voxel_m: float = 0.01,
    on_top: float = 0.0,
) -> tuple[NDArray[np.float64], Scene]:  # fmt: skip
    """A room's fused cloud, as a reconstruction (a SLAM map, a room scan) gives it: the scene
    ``make_scene`` lays out (its keywords), seen by ``views`` cameras (its own, then each turned
    about the objects' middle by 35-70 degrees, alternately to either side, 1.1-1.7 m high and
    looking at it), the views' points fused in the world and thinned to one a ``voxel_m``
    voxel, then moved into a frame of the room's own: z up, the origin on the floor 0-3 m from
    the objects, turned by any yaw. -> (points (N, 3), the Scene whose ``labels`` (N,) and
    objects' truths are the points', ``depth`` empty)."""
    intrinsics = Intrinsics.from_fov(width, height, fov_deg)
    layout = _layout(shapes, rng, intrinsics, width, height, touching, categories, pitch_deg,
                     most, cut_off, distractors, against_wall, on_top)  # fmt: skip
    middle = np.mean([invert_rigid(t.pose)[:3, 3] for t in layout.truths], axis=0)
    ahead = (middle - layout.camera[:3, 3])[[0, 2]]
    reach, heading = float(np.linalg.norm(ahead)), math.atan2(ahead[0], ahead[1])
    cameras = [layout.camera]
    for k in range(1, views):
        turn = heading + (1 if k % 2 else -1) * math.radians(rng.uniform(35, 70))
        lift = rng.uniform(1.1, 1.7)
        look = world_from_camera(lift, math.degrees(math.atan2(lift - middle[1], reach)), 0.0)
        yaw = np.eye(4)
        yaw[:3, :3] = axis_angle_to_matrix([0.0, 1.0, 0.0], turn)
        yaw[:3, 3] = middle - reach * np.array([math.sin(turn), 0.0, math.cos(turn)])
        yaw[1, 3] = 0.0
        cameras.append(yaw @ look)
    points, labels = [], []
    for camera in cameras:
        depth, seen = render(layout.rendered, camera, layout.wall, intrinsics, width, height,
                             rng, flying_pixels, sensor)  # fmt: skip
        cloud, pixels = depth_to_cloud(depth, intrinsics)
        points.append(cloud @ camera[:3, :3].T + camera[:3, 3])
        labels.append(seen.ravel()[pixels])
    world, label = np.concatenate(points), np.concatenate(labels)
    label[label > layout.counted] = 0  # what hangs on the wall is wall
    _, first = np.unique(np.floor(world / voxel_m).astype(np.int64), axis=0, return_index=True)
    world, label = world[first], label[first]
    room_from_world = np.eye(4)  # world y up -> room z up, turned, the origin on the floor
    turn = axis_angle_to_matrix([0.0, 0.0, 1.0], rng.uniform(0, 2 * math.pi))
    room_from_world[:3, :3] = turn @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    offset = rng.uniform(0.0, 3.0) * np.array([*np.sign(rng.normal(size=2)), 0.0])
    room_from_world[:3, 3] = -(room_from_world[:3, :3] @ np.array([middle[0], 0.0, middle[2]]))
    room_from_world[:3, 3] += offset
    world_from_room = invert_rigid(room_from_world)
    truths = [SceneObjectTruth(t.category, t.name, t.pose @ world_from_room, t.radius)
              for t in layout.truths]  # fmt: skip
    room = world @ room_from_world[:3, :3].T + room_from_world[:3, 3]
    return room, Scene(np.zeros((0, 0)), intrinsics, label, truths, layout.others)


@dataclass
class _Layout:
    """A scene before it is seen: its camera (T_world_from_camera (4, 4)) and intrinsics, what
    is rendered ((shape, metres per unit, T_world_from_canonical)), of which the first
    ``counted`` are objects and things (the rest hang on the wall), the wall (world normal (3,),
    offset), the objects' truths in the world frame and the things' kinds."""

    camera: NDArray[np.float64]
    intrinsics: Intrinsics
    rendered: list[tuple[Shape, float, NDArray]]
    counted: int
    wall: tuple[NDArray, float]
    truths: list[SceneObjectTruth]
    others: list[str]


def _layout(
    shapes: dict[str, list[Shape]], rng: np.random.Generator, intrinsics: Intrinsics,
    width: int, height: int, touching: bool, categories: tuple[str, ...],
    pitch_deg: tuple[float, float], most: int, cut_off: bool, distractors: int,
    against_wall: bool, on_top: float = 0.0,
) -> _Layout:  # fmt: skip
    """Where ``make_scene``'s camera, objects, things and wall stand (its draws, in order)."""
    camera = world_from_camera(rng.uniform(1.1, 1.7), rng.uniform(*pitch_deg), rng.uniform(-3, 3))
    view = _View(intrinsics, invert_rigid(camera), width, height, cut_off)
    placed: list[tuple[Shape, float, NDArray, str, float]] = []
    wanted = int(rng.integers(2 if touching else 1, most + 1))
    for _ in range(60):
        if len(placed) == wanted:
            break
        category = categories[int(rng.integers(len(categories)))]
        shape = shapes[category][int(rng.integers(len(shapes[category])))]
        scale = _size_scale(shape, category, rng)
        where = view.place(shape, scale, placed, rng, touching)
        if where is not None:
            placed.append((shape, scale, where, category, _footprint(shape, scale)))
    others = _distractors(view, placed, distractors, rng.spawn(1)[0]) if distractors else []
    wall_turn = math.radians(rng.uniform(-30, 30))
    wall_normal = np.array([-math.sin(wall_turn), 0.0, -math.cos(wall_turn)])  # toward the camera
    # behind every object, 0.3-1.5 m beyond its footprint
    wall_normal_offset = max(
        [float(-wall_normal @ p[2][:3, 3]) + p[4] for p in placed + others] or [3.0]
    ) + rng.uniform(0.3, 1.5)
    rendered = [(s, k, w) for s, k, w, _, _ in placed + others]
    counted = len(rendered)
    if against_wall:
        wall_normal_offset, on_wall = _against_wall(rendered, wall_normal, camera, rng.spawn(1)[0])
        rendered += on_wall
    if on_top > 0:  # drawn last: the scene is otherwise the one drawn without
        rendered[: len(placed)] = _carrying(rendered[: len(placed)], on_top, rng.spawn(1)[0])
    # canonical in metres: the unit shape scaled, then placed (T_canonical_from_world)
    truths = [SceneObjectTruth(category, shape.name, invert_rigid(world), scale)
              for shape, scale, world, category, _ in placed]  # fmt: skip
    return _Layout(camera, intrinsics, rendered, counted, (wall_normal, wall_normal_offset),
                   truths, [kind for _, _, _, kind, _ in others])  # fmt: skip


def _carrying(
    objects: list[tuple[Shape, float, NDArray]], chance: float, rng: np.random.Generator
) -> list[tuple[Shape, float, NDArray]]:  # fmt: skip
    """The rendered ``objects`` (shape, metres per unit, T_world_from_canonical), each carrying
    one to three things on its tops with probability ``chance``
    (``model.surroundings.on_top_things``): its shape's points and discs then hold theirs too,
    so that they render, and are labelled, as part of it (as a box drawn around the piece would
    hold them)."""
    out = []
    for shape, scale, world in objects:
        things = []
        if rng.random() < chance:
            normals, spacing = shape.discs()
            typical = float(np.median(spacing))
            count = int(rng.integers(ON_TOP_COUNT[0], ON_TOP_COUNT[1] + 1))
            things = on_top_things(shape.points, count, typical, 1.0 / scale, rng)
        if things:
            added = np.concatenate([p for p, _ in things])
            discs = (np.concatenate([normals, *[n for _, n in things]]),
                     np.concatenate([spacing, np.full(len(added), typical)]))  # fmt: skip
            shape = Shape(shape.name, np.concatenate([shape.points, added]), _discs=discs)
        out.append((shape, scale, world))
    return out


def _against_wall(
    rendered: list[tuple[Shape, float, NDArray]], normal: NDArray, camera: NDArray,
    rng: np.random.Generator,
) -> tuple[float, list[tuple[Shape, float, NDArray]]]:  # fmt: skip
    """The wall (normal (3,) toward the camera) 0-4 cm behind the farthest of the ``rendered``
    (shape, scale, T_world_from_canonical) -> (its offset, what hangs on it: a skirting board
    along it and one to three pictures or mirrors near the things before it, 0.6-1.9 m up)."""
    reach = [float((-(s.points * k @ w[:3, :3].T + w[:3, 3]) @ normal).max())
             for s, k, w in rendered]  # fmt: skip
    offset = max(reach or [3.0]) + rng.uniform(0.0, 0.04)
    along = np.cross([0.0, 1.0, 0.0], normal)
    rotation = np.stack([along, [0.0, 1.0, 0.0], normal], axis=1)  # the thing's x, y, z

    def on_wall(shape: Shape, scale: float, at: float, height: float) -> tuple:
        depth = scale * float(np.ptp(shape.points[:, 2]))
        world = np.eye(4)
        world[:3, :3] = rotation
        world[:3, 3] = -offset * normal + at * along + [0.0, height, 0.0] + normal * depth / 2
        return shape, scale, world

    skirting, scale = hung("skirting", rng)
    height = scale * float(np.ptp(skirting.points[:, 1])) / 2
    things = [on_wall(skirting, scale, float(camera[:3, 3] @ along), height)]
    for _ in range(int(rng.integers(1, 4))):
        shape, scale = hung(("picture", "mirror")[int(rng.integers(2))], rng)
        near = rendered[int(rng.integers(len(rendered)))][2][:3, 3] if rendered else camera[:3, 3]
        things.append(on_wall(shape, scale, float(near @ along) + rng.uniform(-0.8, 0.8),
                              rng.uniform(0.6, 1.9)))  # fmt: skip
    return offset, things


def _footprint(shape: Shape, scale: float) -> float:
    """How far (m) a placed shape reaches along the floor from its centre."""
    return scale * float(np.linalg.norm(shape.points[:, [0, 2]], axis=1).max())


@dataclass
class _View:
    """Where a scene's camera sees: what ``place`` needs to stand a shape in its view."""

    intrinsics: Intrinsics
    camera_from_world: NDArray[np.float64]
    width: int
    height: int
    cut_off: bool

    def place(
        self, shape: Shape, scale: float, placed: list[tuple[Shape, float, NDArray, str, float]],
        rng: np.random.Generator, touching: bool = False,
    ) -> NDArray[np.float64] | None:  # fmt: skip
        """T_world_from_canonical (4, 4) of the unit ``shape`` scaled by ``scale``, turned by
        any yaw and standing on the floor 1.8-4.5 m ahead, inside the view (its lower part may
        lie below it with ``cut_off``) and 15 cm apart from the ``placed`` (``touching``:
        against one of them); None where the draw fails those."""
        turn = axis_angle_to_matrix([0.0, 1.0, 0.0], rng.uniform(0, 2 * math.pi))
        bearing = math.radians(rng.uniform(-22, 22))
        reach = rng.uniform(1.8, 4.5)
        floor_y = -float(shape.points[:, 1].min()) * scale  # the bottom on the floor
        where = np.array([reach * math.sin(bearing), floor_y, reach * math.cos(bearing)])
        footprint = _footprint(shape, scale)
        if touching and placed:
            against = _against(shape, scale, turn, floor_y, placed, rng)
            if against is None:
                return None
            where = against
        elif any(np.hypot(*(where - p[2][:3, 3])[[0, 2]]) < footprint + p[4] + 0.15
                 for p in placed):  # fmt: skip
            return None
        corners = (shape.points * scale) @ turn.T + where
        cam = corners @ self.camera_from_world[:3, :3].T + self.camera_from_world[:3, 3]
        u = self.intrinsics.fx * cam[:, 0] / cam[:, 2] + self.intrinsics.cx
        v = self.intrinsics.fy * cam[:, 1] / cam[:, 2] + self.intrinsics.cy
        if (
            cam[:, 2].min() < 0.5
            or u.min() < 0
            or u.max() >= self.width
            or v.min() < 0
            or (v.max() >= self.height and not self.cut_off)
        ):
            return None
        world = np.eye(4)
        world[:3, :3], world[:3, 3] = turn, where
        return world


def _distractors(
    view: _View, placed: list[tuple[Shape, float, NDArray, str, float]], most: int,
    rng: np.random.Generator,
) -> list[tuple[Shape, float, NDArray, str, float]]:  # fmt: skip
    """One to ``most`` things of no category (``model.distractors``), each placed in the view
    apart from the ``placed`` objects and from each other, as (shape, scale, world, kind,
    footprint)."""
    others: list[tuple[Shape, float, NDArray, str, float]] = []
    wanted = int(rng.integers(1, most + 1))
    for _ in range(40):
        if len(others) == wanted:
            break
        kind = KINDS[int(rng.integers(len(KINDS)))]
        shape, scale = distractor(kind, rng)
        where = view.place(shape, scale, placed + others, rng)
        if where is not None:
            others.append((shape, scale, where, kind, _footprint(shape, scale)))
    return others


class SceneKind(BaseModel):
    """Which scenes ``make_scene`` makes (its keywords by :meth:`keywords`)."""

    model_config = ConfigDict(extra="forbid")

    draw: str | None = Field(
        default=None, description="the categories drawn, comma-separated (default: every one)"
    )
    pitch: str = Field(
        default="0,25", description="the camera's pitch down, degrees: LOW,HIGH (0,0: level)"
    )
    most: int = Field(default=3, ge=1, description="objects a scene holds at most")
    cut_off: bool = Field(default=False, description="objects' lower parts may lie below the view")
    flying_pixels: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="the share of depth-edge pixels mixed with what lies behind them, as a "
        "time-of-flight camera's are",
    )

    distractors: int = Field(
        default=0,
        ge=0,
        description="up to this many things of no category (ottomans, bins, lamps, plants, "
        "cabinets) among the objects",
    )

    against_wall: bool = Field(
        default=False,
        description="the wall right behind the farthest object, pictures, mirrors and a "
        "skirting board on it",
    )

    on_top: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="the chance that an object carries things on its top (a lamp, books, a "
        "vase, a plant, a mirror)",
    )

    sensor: str | None = Field(
        default=None,
        description="the depth as this camera returns it: kinect_v1, kinect_v2, realsense_d435 "
        "or clean (default: structured-light noise and a few dropped pixels)",
    )

    @field_validator("sensor")
    @classmethod
    def _a_camera(cls, sensor: str | None) -> str | None:
        if sensor is not None and sensor not in SENSORS:
            raise ValueError(f"sensor: unknown camera {sensor!r} (known: {', '.join(SENSORS)})")
        return sensor

    def keywords(self, drawn: tuple[str, ...]) -> dict[str, Any]:
        """``make_scene``'s keywords (``categories``, ``pitch_deg``, ``most``, ``cut_off``,
        ``flying_pixels``, ``distractors``, ``sensor``, ``against_wall``, ``on_top``);
        ``drawn``: the categories without ``draw``. ValueError for a category
        without scenes or a pitch that is not LOW,HIGH."""
        if self.draw is not None:
            drawn = tuple(self.draw.split(","))
            if unknown := set(drawn) - set(WITH_DESKS):
                raise ValueError(f"draw: no scenes of {sorted(unknown)}; choose among {WITH_DESKS}")
        try:
            low, high = (float(x) for x in self.pitch.split(","))
        except ValueError:
            raise ValueError(f"pitch: expected LOW,HIGH in degrees, got {self.pitch!r}") from None
        return {"categories": drawn, "pitch_deg": (low, high), "most": self.most,
                "cut_off": self.cut_off, "flying_pixels": self.flying_pixels,
                "distractors": self.distractors, "sensor": self.sensor,
                "against_wall": self.against_wall, "on_top": self.on_top}  # fmt: skip


def add_kind_arguments(parser: argparse.ArgumentParser, drawn_default: str) -> None:
    """``SceneKind``'s fields as a benchmark's argparse options (read back by ``scene_kind``);
    ``drawn_default`` says what is drawn without ``--draw``."""
    for name, spec in SceneKind.model_fields.items():
        flag = "--" + name.replace("_", "-")
        help_text = (spec.description or "").replace("every one", drawn_default)
        if spec.annotation is bool:
            parser.add_argument(flag, action="store_true", help=help_text)
        else:
            kind = {int: int, float: float}.get(spec.annotation, str)  # type: ignore[call-overload]
            parser.add_argument(flag, type=kind, default=spec.default, help=help_text)


def scene_kind(
    args: argparse.Namespace, parser: argparse.ArgumentParser, drawn: tuple[str, ...]
) -> dict[str, Any]:
    """The options of ``add_kind_arguments`` -> ``make_scene``'s keywords (``SceneKind``); a
    usage error (``parser.error``) for one that ``SceneKind`` refuses."""
    try:
        kind = SceneKind(**{name: getattr(args, name) for name in SceneKind.model_fields})
        return kind.keywords(drawn)
    except (ValueError, ValidationError) as err:
        parser.error(str(err))
