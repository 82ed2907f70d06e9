"""Finding the objects of a scene cloud: the floor (and up), the walls, and clusters of what
stands on the floor, filtered by size.

1. The floor: the largest plane whose normal lies within ``max_tilt_deg`` of the expected up
   and that has nothing below it (``planes.ransac_plane``); up is its normal, toward the
   camera. Points within
   ``floor_threshold_m`` of it, or below it, are floor.
2. The walls: up to ``max_walls`` vertical planes among the rest, each kept only where it is
   larger than furniture (wider than ``wall_min_width_m`` or reaching ``wall_min_top_m`` above
   the floor) and nothing is seen behind it (at most ``wall_max_behind`` of the points lie
   farther than ``wall_behind_m`` beyond it: a wall hides what is behind it, while the plane of
   a sofa's back or a bed's side has the room behind it); points within ``wall_threshold_m`` of a
   wall, or behind it, are wall. The search goes on past a plane that is not a wall, and skips
   what lies within ``wall_behind_m`` of a wall found (its noise, which would be found again).
3. Clusters: what is left, in voxels of ``voxel_m``, linked where voxels lie within ``link_m``
   (3-D) or their footprints on the floor within ``footprint_m`` (so the parts of one object that
   occlusion cut apart, a chair's back above a table, stay one object): the connected components
   (scipy's KD-tree and csgraph).
4. Filters: at least ``min_points`` points, a top at least ``min_height_m`` above the floor (no
   floor fragments), at most ``max_size_m`` across and tall (no room-sized leftovers), its
   median point farther than ``wall_piece_m`` from every wall (a wall's noise, in front of the
   plane by more than its threshold, is a thin sheet that would otherwise pass).
5. Pieces: a cluster that does not reach down to the floor (its lowest point higher than
   ``max_base_m``, where the floor is seen within ``attach_m`` under its lowest points) or stays
   low (its top below ``min_object_m``) is a piece of an object that occlusion or a thin part
   cut off (a table's top behind a chair, a chair's leg below its seat): it joins the nearest
   object within ``attach_m``, or is dropped. A cluster nearer the camera than any floor it
   sees stands all the same (a level camera at head height sees the floor from a few metres on:
   what is nearer shows no base). A standing cluster with at most ``sliver_share`` of the points
   of an object within ``sliver_m`` of it (a side panel or a leg that a gap of a few centimetres
   cut off), or with at most ``far_sliver_share`` of them within ``far_sliver_m``, is a piece of
   that object too.
6. Objects standing against each other: a cluster is cut by a vertical plane where the cut
   judge finds that it holds two objects (``itnet.scene.touching``; ``split_touching``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from itnet.scene.planes import Plane, floor_axes, ransac_plane
from itnet.scene.touching import load_cut_judge, split_touching
from itnet.scene.view_edges import ViewEdges

CAMERA_UP = (0.0, -1.0, 0.0)  # a camera whose image y points down, held about level


@dataclass(frozen=True)
class SegmentOptions:
    """How objects are cut out of a scene (metres)."""

    max_tilt_deg: float = 45.0  # the floor's normal within this of the expected up
    floor_threshold_m: float = 0.03
    # RANSAC hypotheses for the floor, half of them from neighbouring points: a level camera's
    # floor is a tenth of what it sees (a twentieth with objects near it), and 200 drawn
    # anywhere left it 5-45 degrees off in 9% of such frames (docs/scenes.md, step 1)
    floor_hypotheses: int = 2000
    floor_beyond_m: float | None = 0.1  # a point this far below a floor counts against it
    wall_threshold_m: float = 0.04
    max_walls: int = 3
    wall_min_width_m: float = 2.5
    wall_min_top_m: float = 1.6
    # ... or seen up to within this of the view's top edge (a camera pitched down sees only a
    # wall's lower part)
    wall_view_top_deg: float = 1.0
    wall_min_share: float = 0.03  # of the points left after the floor
    wall_behind_m: float = 0.25  # a point this far beyond a plane is seen behind it ...
    wall_max_behind: float = 0.02  # ... and a wall has at most this share of the points so
    voxel_m: float = 0.03
    link_m: float = 0.07
    footprint_m: float = 0.04
    wall_piece_m: float = 0.15  # a cluster whose median point lies this near a wall is of it
    max_base_m: float = 0.15  # a cluster whose lowest point is higher floats: a piece ...
    min_object_m: float = 0.35  # ... as is one whose top is lower (a leg seen below a seat) ...
    attach_m: float = 0.3  # ... of the object within this, else no object
    sliver_m: float = 0.10  # a standing cluster this near an object ...
    sliver_share: float = 0.3  # ... with at most this share of its points is a piece of it
    far_sliver_m: float = 0.20  # so is one this near an object ...
    far_sliver_share: float = 0.2  # ... with at most this share of its points
    min_points: int = 80
    min_height_m: float = 0.2
    max_size_m: float = 3.0
    max_points: int = 80_000  # a larger cloud is segmented on a random subset (see ``segment``)
    split_touching: bool = True  # a cluster cut where the cut judge finds two objects (step 6)


@dataclass
class Segmentation:
    """What ``segment`` found: the floor (None where there is none), ``up`` (3,) (the floor's
    normal toward the camera, else the expected up), the walls, each object's point indices
    into the cloud, largest first, and the view's edges (None where no point lies ahead)."""

    floor: Plane | None
    up: NDArray[np.float64]
    walls: list[Plane] = field(default_factory=list)
    objects: list[NDArray[np.int64]] = field(default_factory=list)
    edges: ViewEdges | None = None


def find_floor(
    points: NDArray, expected_up: NDArray, options: SegmentOptions, rng: np.random.Generator
) -> Plane | None:
    """The floor plane of a camera-frame cloud (N, 3), its normal toward the camera (the
    origin), or None where no plane is near-normal to ``expected_up`` (3,, unit)."""
    cos_tilt = math.cos(math.radians(options.max_tilt_deg))
    found = ransac_plane(
        points,
        rng,
        options.floor_threshold_m,
        lambda n: np.abs(n @ expected_up) > cos_tilt,
        hypotheses=options.floor_hypotheses,
        beyond_m=options.floor_beyond_m,
        local=options.floor_hypotheses // 2,
    )
    if found is None:
        return None
    plane, _ = found
    if plane.offset < 0:  # toward the camera: the camera's height is positive
        plane = Plane(-plane.normal, -plane.offset)
    if plane.normal @ expected_up < cos_tilt:  # a ceiling, seen from below
        return None
    return plane


def find_walls(
    points: NDArray, up: NDArray, floor: Plane, options: SegmentOptions, rng: np.random.Generator,
    edges: ViewEdges | None,
) -> list[Plane]:  # fmt: skip
    """Vertical planes larger than furniture with nothing seen behind them, among points (N, 3)
    above the floor, each normal toward the camera (see the module); ``edges``: the view's."""
    walls: list[Plane] = []
    left = points
    sin_vertical = math.sin(math.radians(10.0))
    for _ in range(2 * options.max_walls):  # planes that are not walls are passed over
        if len(walls) == options.max_walls or len(left) < options.min_points:
            break
        found = ransac_plane(
            left, rng, options.wall_threshold_m, lambda n: np.abs(n @ up) < sin_vertical
        )
        if found is None:
            break
        plane, inliers = found
        if inliers.sum() < options.wall_min_share * len(points):
            break
        along = np.cross(plane.normal, up)
        span = np.percentile(left[inliers] @ along, [2, 98])
        top = np.percentile(floor.distance(left[inliers]), 98)
        small = span[1] - span[0] < options.wall_min_width_m and top < options.wall_min_top_m
        if small and (
            edges is None or "top" not in edges.reached(left[inliers], options.wall_view_top_deg)
        ):
            # furniture-sized (a steep camera sees more of its objects' sides than a wall)
            left = left[~inliers]
            continue
        facing = plane if plane.offset >= 0 else Plane(-plane.normal, -plane.offset)
        behind = np.mean(facing.distance(points) < -options.wall_behind_m)
        if behind <= options.wall_max_behind:
            walls.append(facing)
            left = left[facing.distance(left) > options.wall_behind_m]
        else:  # a large flat side of furniture, with the room seen behind it
            left = left[~inliers]
    return walls


def clusters(points: NDArray, up: NDArray, options: SegmentOptions) -> list[NDArray[np.int64]]:
    """Points (N, 3) standing on the floor -> connected groups of them (indices into
    ``points``), linked in 3-D and by footprint (see the module)."""
    if len(points) == 0:
        return []
    voxel_of, centres = _voxels(points, options.voxel_m)
    # the footprint: voxels over one cell of the floor are one object's (a star per cell)
    cell_of, _ = _voxels(_footprint(centres, up), options.footprint_m)
    first = np.full(cell_of.max() + 1, -1)
    first[cell_of[::-1]] = np.arange(len(cell_of))[::-1]  # each cell's first voxel
    stars = np.stack([np.arange(len(cell_of)), first[cell_of]], axis=1)
    links = cKDTree(centres).query_pairs(options.link_m, output_type="ndarray")
    pairs = np.concatenate([links.reshape(-1, 2), stars])
    n = len(centres)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label_of_voxel = connected_components(graph, directed=False)
    labels = label_of_voxel[voxel_of]
    order = np.argsort(labels, kind="stable")
    bounds = np.flatnonzero(np.diff(labels[order])) + 1
    return list(np.split(order, bounds))


def _voxels(points: NDArray, size: float) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Points (N, D) -> (each point's voxel (N,), the voxels' centroids (V, D)) on a grid of
    ``size``."""
    keys = np.floor(points / size).astype(np.int64)
    keys -= keys.min(axis=0)
    span = keys.max(axis=0) + 1
    flat = np.ravel_multi_index(keys.T, span)
    _, voxel_of, counts = np.unique(flat, return_inverse=True, return_counts=True)
    centres = np.stack(
        [np.bincount(voxel_of, points[:, k]) / counts for k in range(points.shape[1])], axis=1
    )
    return voxel_of, centres


def standing(
    points: NDArray, heights: NDArray, up: NDArray, walls: list[Plane], options: SegmentOptions
) -> bool:
    """Whether a cluster (K, 3), its points' heights above the floor (K,), is an object's
    size and not a piece of a wall: enough points, tall enough, not larger than a room's
    furniture, not lying along a wall."""
    if len(points) < options.min_points:
        return False
    if any(np.median(np.abs(w.distance(points))) < options.wall_piece_m for w in walls):
        return False
    top = float(np.percentile(heights, 98))
    if top < options.min_height_m or top - float(heights.min()) > options.max_size_m:
        return False
    flat = points - np.outer(points @ up, up)
    lo, hi = np.percentile(flat, [1, 99], axis=0)
    return float(np.linalg.norm(hi - lo)) <= options.max_size_m * math.sqrt(2)


def attach_pieces(
    points: NDArray, heights: NDArray, groups: list[NDArray[np.int64]], up: NDArray,
    options: SegmentOptions,
) -> list[NDArray[np.int64]]:  # fmt: skip
    """Clusters (indices into points (N, 3), heights (N,)) -> the ones standing on the floor,
    each with the pieces whose nearest point lies within ``attach_m`` of it. A cluster whose
    base is high stands all the same where it is nearer the camera (the origin), along the
    floor, than any floor the camera sees: its base is below the view (a level camera at head
    height sees the floor only from a few metres on)."""
    floor = np.abs(heights) <= options.floor_threshold_m
    reach = np.linalg.norm(_footprint(points[floor][::4], up), axis=1)  # the camera: 0, 0
    nearest_floor = float(np.percentile(reach, 1)) if len(reach) else np.inf

    def whole(g: NDArray) -> bool:
        top = float(np.percentile(heights[g], 98))
        if top < options.min_object_m:
            return False
        if heights[g].min() <= options.max_base_m:
            return True
        lowest = g[np.argsort(heights[g])[: max(1, len(g) // 10)]]
        return float(np.median(np.linalg.norm(_footprint(points[lowest], up), axis=1))) < (
            nearest_floor
        )

    based = slivers_joined(points, [g for g in groups if whole(g)], options)
    if not based:
        return []
    trees = [cKDTree(points[g]) for g in based]
    joined = [[g] for g in based]
    for piece in (g for g in groups if not whole(g)):
        gaps = [_gap(points, piece, tree) for tree in trees]
        nearest = int(np.argmin(gaps))
        if gaps[nearest] <= options.attach_m:
            joined[nearest].append(piece)
    return [np.sort(np.concatenate(parts)) for parts in joined]


def slivers_joined(
    points: NDArray, groups: list[NDArray[np.int64]], options: SegmentOptions
) -> list[NDArray[np.int64]]:
    """Standing clusters (indices into points (N, 3)) -> the same, each small one that lies
    within ``sliver_m`` of a cluster with at least 1 / ``sliver_share`` times its points, or
    within ``far_sliver_m`` of one with at least 1 / ``far_sliver_share`` times, joined to the
    nearest such (smallest first, so a chain of pieces ends in its object)."""
    parts: list[list[NDArray[np.int64]] | None] = [[g] for g in groups]
    sizes = [len(g) for g in groups]
    trees: dict[int, cKDTree] = {}
    for i in sorted(range(len(groups)), key=lambda k: sizes[k]):
        larger = [j for j in range(len(groups)) if sizes[i] <= options.sliver_share * sizes[j]]
        if not larger:
            continue
        gaps = []
        for j in larger:
            if j not in trees:
                trees[j] = cKDTree(points[groups[j]])
            gap = _gap(points, groups[i], trees[j])
            near = gap <= options.sliver_m or (
                gap <= options.far_sliver_m and sizes[i] <= options.far_sliver_share * sizes[j]
            )
            gaps.append(gap if near else np.inf)
        nearest = int(np.argmin(gaps))
        if np.isfinite(gaps[nearest]):
            owner, mine = parts[larger[nearest]], parts[i]
            assert owner is not None and mine is not None  # larger ones are merged later
            owner.extend(mine)
            parts[i] = None
    return [np.sort(np.concatenate(p)) for p in parts if p is not None]


def _gap(points: NDArray, piece: NDArray[np.int64], tree: cKDTree) -> float:
    """How near a cluster (indices into points (N, 3)) comes to the points of ``tree``, from
    about 200 of its points."""
    sample = points[piece[:: max(1, len(piece) // 200)]]
    return float(tree.query(sample, k=1)[0].min())


def _footprint(points: NDArray, up: NDArray) -> NDArray[np.float64]:
    """Points (N, 3) -> their places on the floor (N, 2): coordinates along two directions
    normal to ``up``."""
    across, along = floor_axes(up)
    return np.stack([points @ across, points @ along], axis=1)


def segment(
    points: NDArray,
    options: SegmentOptions = SegmentOptions(),
    expected_up: NDArray | tuple[float, float, float] = CAMERA_UP,
    seed: int = 0,
) -> Segmentation:
    """A scene cloud (N, 3) in the camera's frame, metres -> its Segmentation (see the
    module). ``expected_up``: roughly which way is up in the cloud (the floor is searched
    within ``max_tilt_deg`` of it)."""
    rng = np.random.default_rng(seed)
    edges = ViewEdges.of_points(points)
    prior = np.asarray(expected_up, dtype=np.float64)
    prior = prior / np.linalg.norm(prior)
    subset = None
    if len(points) > options.max_points:  # a 640x480 frame: the planes and clusters on a subset
        subset = np.sort(rng.choice(len(points), options.max_points, replace=False))
    work = points if subset is None else points[subset]
    floor = find_floor(work, prior, options, rng)
    if floor is None:
        return Segmentation(None, prior, edges=edges)
    up = floor.normal
    heights = floor.distance(work)
    keep = heights > options.floor_threshold_m
    walls = find_walls(work[keep], up, floor, options, rng, edges)
    for wall in walls:
        keep &= wall.distance(work) > options.wall_threshold_m
    index = np.flatnonzero(keep)
    groups = [index[g] for g in clusters(work[index], up, options)]
    objects = [g for g in groups if standing(work[g], heights[g], up, walls, options)]
    objects = attach_pieces(work, heights, objects, up, options)
    judge = load_cut_judge() if options.split_touching else None
    if judge is not None:
        objects = split_touching(work, objects, floor, judge)
    if subset is not None:
        objects = spread(points, floor, walls, [subset[g] for g in objects], options)
    objects.sort(key=len, reverse=True)
    return Segmentation(floor, up, walls, objects, edges)


def spread(
    points: NDArray, floor: Plane, walls: list[Plane], objects: list[NDArray[np.int64]],
    options: SegmentOptions,
) -> list[NDArray[np.int64]]:  # fmt: skip
    """Objects found on a subset of ``points`` (N, 3) (indices into it) -> every point that is
    neither floor nor wall joins the object whose subset points share its voxel (indices)."""
    if not objects:
        return []
    keep = floor.distance(points) > options.floor_threshold_m
    for wall in walls:
        keep &= wall.distance(points) > options.wall_threshold_m
    index = np.flatnonzero(keep)
    cells = np.floor(points[index] / options.voxel_m).astype(np.int64)
    cells -= cells.min(axis=0)
    keys = np.asarray(np.ravel_multi_index(cells.T, cells.max(axis=0) + 1), dtype=np.int64)
    owned = np.concatenate([keys[np.searchsorted(index, rows)] for rows in objects])
    owner = np.concatenate([np.full(len(rows), k) for k, rows in enumerate(objects)])
    owned, first = np.unique(owned, return_index=True)
    where = np.minimum(np.searchsorted(owned, keys), len(owned) - 1)
    hit = owned[where] == keys
    label = owner[first][where]
    return [index[hit & (label == k)] for k in range(len(objects))]
