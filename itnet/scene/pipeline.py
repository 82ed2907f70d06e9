"""``find_objects``: a scene in, every object's category and pose out, within one budget.

    result = find_objects(depth_image, Intrinsics(fx, fy, cx, cy), budget_ms=100)
    for obj in result.objects:
        obj.category, obj.pose        # T_canonical_from_input (4, 4), or None

The clock starts when the call does (or at ``started``): reading the scene's points,
segmenting them (``segment``), then one object after another, largest first, each given an
equal share of what is left of ``budget_ms`` (an object that finishes early leaves its time to
the next). Each object is classified and posed with up (the floor's normal) and the viewpoint
(the camera) given (``posing.pose_object``).

Then the object stands on the floor (``floor_centred``): its canonical origin is the centre of
its bounding box, whose bottom is the floor, so the centre's height is half the object's top.
The top is what the camera sees best (it looks down on furniture); the network places the
centre of a partial view too near the surface it sees, and the floor says how high it is.
Before that, where the pose model has a scene correction (``centre_along_floor``), the centre
moves along the floor to where it predicts. Last, a pose the category's verifier doubts is
weighed against a pose as its second candidate category (``category_recheck``). Each of
these steps is a switch of ``SceneFinishing``. The category itself is named by the scene
classifier where it applies (``scene_classifier``), else by the classifier and the height.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.columns import column_max, column_mean, column_min, percentiles
from itnet.planes import Plane
from itnet.pose.catalog import Catalog
from itnet.scene.camera import Intrinsics, SceneInputError
from itnet.scene.category_recheck import rechecked
from itnet.scene.centre_along_floor import CentreTable, centred_along_floor, load_table
from itnet.scene.inputs import SceneInput, SceneLimits, from_array, from_file
from itnet.scene.named_split import Namer, named_parts
from itnet.scene.posing import (
    BadCloudError,
    ObjectPose,
    pose_object,
    scene_catalog,
    top_height,
    with_pose,
)
from itnet.scene.request import DEFAULT_BUDGET_MS, SceneFinishing, up_direction
from itnet.scene.result import Box, SceneObject, SceneResult
from itnet.scene.room import segment_scene
from itnet.scene.scene_classifier import SceneClassifier, load_scene_classifier
from itnet.scene.segment import (
    CAMERA_UP,
    Segmentation,
    SegmentOptions,
    working_points,
)
from itnet.scene.touching import load_cut_judge
from itnet.scene.view_edges import ViewEdges

VIEWPOINT = np.zeros(3)  # a camera's view's camera, in its own frame (the fits look from it)


def find_objects(
    scene: NDArray | str | Path | SceneInput,
    intrinsics: Intrinsics | None = None,
    budget_ms: float = DEFAULT_BUDGET_MS,
    catalog: Catalog | None = None,
    depth_scale: float | None = None,
    options: SegmentOptions = SegmentOptions(),
    expected_up: NDArray | tuple[float, float, float] = CAMERA_UP,
    limits: SceneLimits = SceneLimits(),
    started: float | None = None,
    finishing: SceneFinishing = SceneFinishing(),
    centre_table: CentreTable | None = None,
    categories: frozenset[str] | None = None,
    scene_classifier: SceneClassifier | bool = True,
    room: bool | None = None,
) -> SceneResult:
    """A scene -> its SceneResult. ``scene``: a depth image (H, W) (with ``intrinsics``), a
    cloud (N, 3) in the camera's frame (metres), a file of either, or a SceneInput. ``catalog``:
    the models (default: the shipped ones, loaded once per process, on the first call and before
    its budget's clock starts). ``categories``: the ones the
    scene's objects may be (a bathroom's: toilet, bathtub; default: any the classifier knows).
    ``finishing``: the steps each posed object gets after its pose pipeline; ``centre_table``:
    the pose models' scene corrections (default: the shipped table). ``scene_classifier``: what
    names the objects (``itnet.scene.scene_classifier``): True, the shipped one where it was
    fitted for the catalog's classifier; False, the classifier with the height alone.
    ``expected_up``: roughly which way is up in the camera's frame (default −y: a camera held
    about level; from an IMU's gravity for one pitched 45° or more, or turned on its side): the
    floor is searched within 45° of it. ``room``: the cloud is a room's (a fused reconstruction
    with no camera at its origin; ``itnet.scene.room``): True, False (a camera's view from the
    origin), None (decided from the cloud; a depth image is a camera's). Raises
    SceneInputError for a scene that cannot be used (a depth image asked to be a room's),
    ValueError for a budget that is not positive or an up that is no direction."""
    catalog = catalog or shipped_catalog()  # once a process, before the request's clock
    started = time.perf_counter() if started is None else started
    if not budget_ms > 0:
        raise ValueError(f"budget_ms must be positive, got {budget_ms}")
    try:
        expected = up_direction(expected_up)
    except ValueError as err:
        raise ValueError(f"expected_up: {err}") from None
    if isinstance(scene, SceneInput):
        given = scene
    elif isinstance(scene, (str, Path)):
        given = from_file(Path(scene), intrinsics, depth_scale, limits)
    else:
        given = from_array(np.asarray(scene), intrinsics, depth_scale, limits)
    if options.work_points is None:
        options = replace(options, work_points=working_points(budget_ms))
    try:
        found = segment_scene(given.points, options, expected, room, given.image_shape is not None)
    except ValueError as err:
        raise SceneInputError(str(err)) from None
    segment_ms = (time.perf_counter() - started) * 1e3
    objects = []
    table = load_table() if centre_table is None else centre_table
    if not finishing.along_floor:
        table = CentreTable({})
    namer = serving_scene_classifier(catalog, scene_classifier)
    context = _Context(catalog, found, table, namer, finishing, categories)
    rng = np.random.default_rng(0)
    for k, rows in enumerate(found.objects):
        left_ms = budget_ms - (time.perf_counter() - started) * 1e3
        if not context.can_name(left_ms):  # the budget is spent: boxed, unnamed
            objects.append(_unnamed(found, given.points[rows], given.indices[rows]))
            continue
        objects += _answered(context, given.points[rows], given.indices[rows],
                             left_ms / (len(found.objects) - k), rng)  # fmt: skip
    return SceneResult(
        objects, found.up if found.floor is not None else None, found.floor, found.walls,
        len(given.points), given.image_shape, budget_ms, segment_ms,
        (time.perf_counter() - started) * 1e3, found.room,
    )  # fmt: skip


# an object's category, pose and finishing see at most this many of its points, drawn at
# random (the pose networks read fewer; a near dresser of a 640x480 frame has 60,000)
OBJECT_POINTS = 4096


# What an object's steps after its pose take (standing it on the floor, the recheck's look at
# its verifier, its box): about 1-4 ms on 2 cores. Each object's pose ends this much before its
# share does, the most any object of the scene took so far (at least this), so that the last
# object's finishing does not make the reply late.
FINISH_MS = 4.0


# What answering an object without a pose takes (naming it, standing it on the floor, its box):
# 8-17 ms on 2 cores for a real frame's clusters. Where less than this (the most any object of
# the scene took so far, at least this) and the finishing are left, the objects left are
# answered unnamed (``unknown: "budget"``) with their box and points, at once.
NAME_MS = 8.0


@dataclass
class _FinishClock:
    """The longest a step of this scene's objects took so far (ms): what the next one
    reserves."""

    ms: float = FINISH_MS

    def took(self, ms: float) -> None:
        self.ms = max(self.ms, ms)


@dataclass(frozen=True)
class _Context:
    """What every object of one scene is answered with."""

    catalog: Catalog
    found: Segmentation
    table: CentreTable
    namer: SceneClassifier | None
    finishing: SceneFinishing
    categories: frozenset[str] | None
    finish: _FinishClock = field(default_factory=_FinishClock)
    naming: _FinishClock = field(default_factory=lambda: _FinishClock(NAME_MS))

    def can_name(self, left_ms: float) -> bool:
        """Whether ``left_ms`` of the scene's budget holds one more object's answer."""
        return left_ms >= self.naming.ms + self.finish.ms


def _answered(
    context: _Context, points: NDArray, indices: NDArray[np.int64], share_ms: float,
    rng: np.random.Generator, split: bool = True,
) -> list[SceneObject]:  # fmt: skip
    """One cluster (K, 3), its points' ``indices`` (K,) and its share of the budget (ms) -> its
    SceneObject; the objects of its parts where it is too large for the category it is named
    and the recognition parts it in two (``named_split``, where ``split``); none for a cluster
    the classifier cannot use."""
    found, finishing, catalog = context.found, context.finishing, context.catalog
    now = time.perf_counter()
    seen_points = points if len(points) <= OBJECT_POINTS else points[
        rng.choice(len(points), OBJECT_POINTS, replace=False)]  # fmt: skip
    hidden = base_out_of_view(found.edges, seen_points, found.floor, finishing)
    height = None if found.floor is None else top_height(seen_points, found.floor)
    pose_ms = max(share_ms - context.finish.ms, 0.0)
    try:
        seen = pose_object(catalog, seen_points, found.up, found.viewpoint, pose_ms,
                           categories=context.categories, floor=found.floor,
                           scene_classifier=context.namer, base_hidden=hidden,
                           base_hidden_models=finishing.base_hidden_models,
                           unknown=finishing.unknown)  # fmt: skip
    except BadCloudError:  # a cluster the classifier cannot use (degenerate): no object
        return []
    if seen.unknown == "too_large" and split and finishing.named_split and found.floor is not None:
        parts = _parts(context, points, now + share_ms / 2e3)
        if len(parts) > 1:
            left_ms = share_ms - (time.perf_counter() - now) * 1e3
            return [
                o
                for part in parts
                for o in _answered(
                    context, points[part], indices[part], left_ms / len(parts), rng, split=False
                )
            ]
    if seen.no_pose == "budget":  # named, and no time left for a pose: what naming costs
        context.naming.took((time.perf_counter() - now) * 1e3)
    finishing_from = time.perf_counter()
    finish = partial(stood_on_floor, catalog=catalog, points=seen_points, height=height,
                     found=found, table=context.table, floor_centre=finishing.floor_centre)  # fmt: skip
    seen = finish(seen)
    if finishing.recheck:
        seen = rechecked(catalog, seen, seen_points, found.up, found.viewpoint, now + pose_ms / 1e3,
                         finish, hidden)  # fmt: skip
    box = object_box(points, found.up, found.floor, seen.pose)
    context.finish.took((time.perf_counter() - finishing_from) * 1e3)
    return [SceneObject(indices, seen.category, seen.probability, seen.candidates, seen.unsure,
                        box, seen.pose, seen.result, seen.no_pose, seen.named_by, hidden,
                        seen.unknown)]  # fmt: skip


def _unnamed(found: Segmentation, points: NDArray, indices: NDArray[np.int64]) -> SceneObject:
    """A cluster (K, 3) the scene's budget left no time to name: unknown (``"budget"``), no
    pose, its box along up."""
    box = object_box(points, found.up, found.floor, None)
    return SceneObject(indices, None, 0.0, [], True, box, no_pose="budget", unknown="budget")


def _parts(context: _Context, points: NDArray, deadline: float) -> list[NDArray[np.int64]]:
    """A too large cluster's (K, 3) objects, as the recognition parts it (``named_parts``)."""
    assert context.found.floor is not None
    namer = Namer(context.catalog, context.namer, context.categories, context.found.floor,
                  context.found.viewpoint)  # fmt: skip
    return named_parts(points, namer, load_cut_judge(), deadline)


_SHIPPED: Catalog | None = None


def shipped_catalog() -> Catalog:
    """The shipped models, loaded on first use and kept for the process."""
    global _SHIPPED
    if _SHIPPED is None:
        _SHIPPED = scene_catalog()
    return _SHIPPED


def serving_scene_classifier(
    catalog: Catalog, choice: SceneClassifier | bool = True
) -> SceneClassifier | None:
    """The scene classifier that names a scene's objects: ``choice`` itself, or (True) the
    shipped one, where it was fitted for the catalog's classifier; None (False, or none fits)."""
    if choice is False or catalog.classifier is None:
        return None
    chosen = load_scene_classifier() if choice is True else choice
    return chosen if chosen is not None and chosen.serves(catalog.classifier) else None


def stood_on_floor(
    seen: ObjectPose, catalog: Catalog, points: NDArray, height: float | None, found: Segmentation,
    table: CentreTable, floor_centre: bool = True,
) -> ObjectPose:  # fmt: skip
    """A posed object (its cluster (K, 3), its top ``height`` above the floor) stood on the
    floor: its place along the floor by its pose model's scene correction in ``table`` where it
    has one, its height from the floor (``floor_centred``); unchanged without a pose, or with
    ``floor_centre`` off."""
    if not floor_centre or seen.pose is None or seen.result is None:
        return seen
    assert found.floor is not None and height is not None  # objects stand on a floor
    model = catalog.models[seen.result["model"]]
    correction = table.for_model(model.card.name, model.path)
    if correction is not None:
        try:
            seen.pose = centred_along_floor(points, seen.pose, correction, found.viewpoint,
                                            found.up)  # fmt: skip
        except ValueError:  # the pose puts the camera on the object's centre
            correction = None
    seen.pose = floor_centred(seen.pose, height, found.floor)
    seen.result = with_pose(seen.result, seen.pose) | {
        "centre_floor": True,
        "centre_along_floor": correction is not None,
    }
    return seen


def base_out_of_view(
    edges: ViewEdges | None, points: NDArray, floor: Plane | None, finishing: SceneFinishing,
) -> bool:  # fmt: skip
    """Whether an object's base lies below the view: its points (K, 3) reach within
    ``finishing.view_edge_deg`` of the view's bottom edge (``edges``: the scene's), and the
    lowest of them (2nd percentile) stands above ``finishing.base_low_share`` of its top over the
    ``floor`` (a table whose near legs leave the view while its far ones reach the floor is
    whole enough)."""
    if floor is None:
        return False
    heights = floor.distance(points)
    low, top = percentiles(heights, [2, 98])
    if low < finishing.base_low_share * top:
        return False
    return edges is not None and "bottom" in edges.reached(points, finishing.view_edge_deg)


def floor_centred(pose: NDArray, top: float, floor: Plane) -> NDArray[np.float64]:
    """T_canonical_from_input (4, 4) of an object standing on ``floor`` whose top stands ``top``
    above it (``top_height``) -> the same pose with the object's centre moved along the floor's
    normal to half that height."""
    rotation = pose[:3, :3]
    centre = -rotation.T @ pose[:3, 3]
    centre = centre + (top / 2 - float(floor.distance(centre[None])[0])) * floor.normal
    out = np.array(pose, dtype=np.float64)
    out[:3, 3] = -rotation @ centre
    return out


def object_box(points: NDArray, up: NDArray, floor: Plane | None, pose: NDArray | None) -> Box:
    """The box of an object's points (K, 3) in the camera frame, standing on the floor: along
    its canonical axes where it has a pose (4, 4), else along up and its widest horizontal
    direction. Its bottom reaches down to the floor where there is one."""
    if pose is not None:
        rotation = pose[:3, :3].T  # R_camera_from_canonical: the canonical axes
    else:
        sample = points[:: max(1, len(points) // OBJECT_POINTS)]
        flat = sample - column_mean(sample)
        flat -= np.outer(flat @ up, up)
        _, _, vt = np.linalg.svd(flat, full_matrices=False)
        x = vt[0] - (vt[0] @ up) * up
        x /= np.linalg.norm(x)
        rotation = np.stack([x, up, np.cross(x, up)], axis=1)
    local = points @ rotation
    lo, hi = column_min(local), column_max(local)
    if floor is not None:  # the floor under the box's centre, along the box's y (up)
        height = float(floor.distance(rotation @ ((lo + hi) / 2)))
        lo[1] = min(lo[1], (lo[1] + hi[1]) / 2 - height)
    return Box(rotation @ ((lo + hi) / 2), hi - lo, rotation)


__all__ = [
    "DEFAULT_BUDGET_MS",
    "SceneFinishing",
    "find_objects",
    "object_box",
    "serving_scene_classifier",
    "shipped_catalog",
    "up_direction",
]
