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
   (scipy's KD-tree and csgraph). What lies within ``wall_band_m`` of a wall links nothing:
   pictures, mirrors and mouldings on a wall, its noise, and the backs of the furniture standing
   against it would otherwise join everything along the wall into one cluster; each of its
   voxels joins the cluster it is fewest links from.
4. Filters: at least ``min_points`` working voxels (``least_voxels``), a top at least
   ``min_height_m`` above the floor (no floor fragments), at most ``max_size_m`` across and tall (no
   room-sized leftovers), its median point farther than ``wall_piece_m`` from every wall (a wall's
   noise, in front of the plane by more than its threshold, is a thin sheet that would otherwise
   pass).
5. Pieces: a cluster that does not reach down to the floor (its lowest point higher than
   ``max_base_m``, where the floor is seen within ``attach_m`` under its lowest points) or stays
   low (its top below ``min_object_m``) is a piece of an object that occlusion or a thin part
   cut off (a table's top behind a chair, a chair's leg below its seat): it joins the nearest
   object within ``attach_m``, or is dropped. A cluster nearer the camera than any floor it
   sees stands all the same (a level camera at head height sees the floor from a few metres on:
   what is nearer shows no base). A standing cluster with at most ``sliver_share`` of the points
   of an object within ``sliver_m`` of it (a side panel or a leg that a gap of a few centimetres
   cut off), or with at most ``far_sliver_share`` of them within ``far_sliver_m`` unless it is
   an object beside that one (``_beside``: wide, its footprint mostly outside), is a piece of
   that object too, unless it rises ``sliver_rise_m`` over it. A group of pieces that no
   object takes stands where the floor under it is hidden behind something nearer and it is an
   object's size (``HiddenFloor``: a headboard behind the ottoman at the bed's foot).
6. Objects standing against each other: a cluster is cut by a vertical plane where the cut
   judge finds that it holds two objects (``itnet.scene.touching``; ``split_touching``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import chain

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from itnet.columns import column_max, column_min, percentiles
from itnet.planes import Plane, floor_axes, ransac_plane, refined_plane
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
    wall_min_top_m: float = 2.1  # taller than furniture (a wardrobe is 2.0 m), lower than rooms
    # ... or seen up to within this of the view's top edge (a camera pitched down sees only a
    # wall's lower part)
    wall_view_top_deg: float = 1.0
    wall_min_share: float = 0.03  # of the points left after the floor
    wall_behind_m: float = 0.25  # a point this far beyond a plane is seen behind it ...
    # ... and a wall shows at most this share of what is seen on it or through it (windows,
    # mirrors and doorways show what is behind a real wall; the plane of a large piece of
    # furniture has the room behind it) ...
    wall_max_through: float = 0.25
    # ... or at most this share of the points where it is smaller than a wall and passes only by
    # reaching the view's top (the front of a tall chest beside the camera does too)
    wall_edge_max_behind: float = 0.02
    voxel_m: float = 0.03
    link_m: float = 0.07
    link_voxels: float = 1.6  # ... or this many of the working cloud's voxels, if farther
    footprint_m: float = 0.04
    wall_piece_m: float = 0.15  # a cluster whose median point lies this near a wall is of it
    # what lies this near a wall (things hung on it, mouldings, its noise, the backs of what
    # stands against it) joins a cluster but links none (step 3)
    wall_band_m: float = 0.12
    max_base_m: float = 0.15  # a cluster whose lowest point is higher floats: a piece ...
    min_object_m: float = 0.35  # ... as is one whose top is lower (a leg seen below a seat) ...
    attach_m: float = 0.3  # ... of the object within this, else no object ...
    low_object_m: float = 0.5  # ... unless it stands on the floor and is this wide
    sliver_m: float = 0.10  # a standing cluster this near an object ...
    sliver_share: float = 0.3  # ... with at most this share of its points is a piece of it
    far_sliver_m: float = 0.20  # so is one this near an object ...
    far_sliver_share: float = 0.2  # ... with at most this share of its points
    # ... and whose top rises at most this above that object's (a piece a gap cuts off an object
    # does not stand over it; the mirror of a dresser beside a bed does)
    sliver_rise_m: float = 0.15
    # beyond sliver_m, a cluster as wide as low_object_m with less than this share of its
    # footprint within the object's (grown by far_sliver_m) stands beside it: a panel or a part
    # stands at its object's edge, a dresser beside a bed beside it
    far_sliver_within: float = 0.5
    # a cluster covers at least this much surface: this many of the working cloud's voxels
    # of 3 cm (more of smaller voxels, fewer of larger: ``least_voxels``)
    min_points: int = 12
    # pieces that stand on a floor the camera does not see cover at least this many voxels of
    # 3 cm (a tenth of a square metre: a headboard's or a cabinet's front, more than the pieces
    # that a gap cuts off an object; ``HiddenFloor``) ...
    hidden_min_points: int = 100
    # ... and rise this far from their lowest point to their top (a flat piece, the top of a
    # table or a block seen past what stands before it, is no object of its own)
    hidden_min_rise_m: float = 0.25
    min_height_m: float = 0.2
    max_size_m: float = 3.0
    # the objects' working cloud: the centroids of voxels of this size, or larger where there
    # would be more than work_points (None: as many as the scene's budget affords,
    # ``working_points``), from at most max_input of the scene's points (``VoxelCloud``)
    work_voxel_m: float = 0.03
    work_points: int | None = None
    # the planes are found among voxels of this size of this many of the points
    plane_voxel_m: float = 0.05
    plane_points: int = 30_000
    max_input: int = 100_000
    split_touching: bool = True  # a cluster cut where the cut judge finds two objects (step 6)


@dataclass
class Segmentation:
    """What ``segment`` found: the floor (None where there is none), ``up`` (3,) (the floor's
    normal toward the camera, else the expected up), the walls, each object's point indices
    into the cloud, largest first, the view's edges (None where no point lies ahead, or no
    camera saw the cloud), where it was looked at from (3,): the camera, or a room's lookout,
    and whether it is a room's cloud (``itnet.scene.room``)."""

    floor: Plane | None
    up: NDArray[np.float64]
    walls: list[Plane] = field(default_factory=list)
    objects: list[NDArray[np.int64]] = field(default_factory=list)
    edges: ViewEdges | None = None
    viewpoint: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    room: bool = False


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
        span = percentiles(left[inliers] @ along, [2, 98])
        top = percentiles(floor.distance(left[inliers]), [98])[0]
        small = span[1] - span[0] < options.wall_min_width_m and top < options.wall_min_top_m
        if small and (
            edges is None or "top" not in edges.reached(left[inliers], options.wall_view_top_deg)
        ):
            # furniture-sized (a steep camera sees more of its objects' sides than a wall)
            left = left[~inliers]
            continue
        facing = plane if plane.offset >= 0 else Plane(-plane.normal, -plane.offset)
        behind = int(np.sum(facing.distance(points) < -options.wall_behind_m))
        if (
            behind <= options.wall_edge_max_behind * len(points)
            if small
            else behind <= options.wall_max_through * (behind + int(inliers.sum()))
        ):
            walls.append(facing)
            left = left[facing.distance(left) > options.wall_behind_m]
        else:  # a large flat side of furniture, with the room seen behind it
            left = left[~inliers]
    return walls


def clusters(
    points: NDArray, up: NDArray, options: SegmentOptions, voxel_m: float | None = None,
    band: NDArray[np.bool_] | None = None,
) -> list[NDArray[np.int64]]:  # fmt: skip
    """Points (N, 3) standing on the floor -> connected groups of them (indices into
    ``points``), linked in 3-D and by footprint (see the module). ``voxel_m``: the points are
    already the centroids of voxels this large (``VoxelCloud``), linked within ``link_m`` or
    ``link_voxels`` voxels (neighbours' centroids lie up to two voxels apart), whichever is
    farther. ``band`` (N,): the points in a wall's band, which join groups but link none
    (``_off_the_band``)."""
    if len(points) == 0:
        return []
    if voxel_m is None:
        voxel_of, centres = _voxels(points, options.voxel_m)
        link = options.link_m
    else:  # voxelised again on another grid, centroids of neighbours would leave gaps
        voxel_of, centres = np.arange(len(points)), np.asarray(points, dtype=np.float64)
        link = max(options.link_m, options.link_voxels * voxel_m)
    # the footprint: voxels over one cell of the floor are one object's (a star per cell)
    cell_of, _ = _voxels(_footprint(centres, up), options.footprint_m)
    first = np.full(cell_of.max() + 1, -1)
    first[cell_of[::-1]] = np.arange(len(cell_of))[::-1]  # each cell's first voxel
    stars = np.stack([np.arange(len(cell_of)), first[cell_of]], axis=1)
    links = cKDTree(centres).query_pairs(link, output_type="ndarray").reshape(-1, 2)
    if band is None or not band[voxel_of].any():
        label_of_voxel = _components(len(centres), np.concatenate([links, stars]))
    else:
        in_band = np.zeros(len(centres), bool)
        in_band[voxel_of[band]] = True
        label_of_voxel = _off_the_band(len(centres), links, stars, in_band)
    labels = label_of_voxel[voxel_of]
    order = np.argsort(labels, kind="stable")
    bounds = np.flatnonzero(np.diff(labels[order])) + 1
    return list(np.split(order, bounds))


def _components(n: int, pairs: NDArray) -> NDArray[np.int64]:
    """The connected component (n,) of each of ``n`` nodes linked by ``pairs`` (P, 2)."""
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _off_the_band(
    n: int, links: NDArray, stars: NDArray, in_band: NDArray[np.bool_]
) -> NDArray[np.int64]:
    """Components (n,) of nodes linked by ``links`` (P, 2) and ``stars`` (S, 2) where the nodes
    ``in_band`` (n,) (a wall's band: what hangs on it, its mouldings, its noise, and the backs of
    what stands against it) link no two components: the rest is linked without them, and each
    of them joins the component it is fewest 3-D links from (through the band), or, reaching
    none, one of its own with the band's nodes it links to."""
    pairs = np.concatenate([links, stars])
    label = _components(n, pairs[~in_band[pairs[:, 0]] & ~in_band[pairs[:, 1]]])
    near_band = links[in_band[links[:, 0]] | in_band[links[:, 1]]]
    reached = np.full(n, -1)
    if (~in_band).any() and len(near_band):
        graph = coo_matrix((np.ones(len(near_band)), (near_band[:, 0], near_band[:, 1])),
                           shape=(n, n))  # fmt: skip
        reached = dijkstra(graph, directed=False, indices=np.flatnonzero(~in_band),
                           unweighted=True, min_only=True, return_predecessors=True)[2]  # fmt: skip
    lost = in_band & (reached < 0)
    joined = in_band & ~lost
    label[joined] = label[reached[joined]]
    if lost.any():
        own = _components(n, links[lost[links[:, 0]] & lost[links[:, 1]]])
        label[lost] = label.max() + 1 + own[lost]
    return label


def _voxels(points: NDArray, size: float) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Points (N, D) -> (each point's voxel (N,), the voxels' centroids (V, D)) on a grid of
    ``size``."""
    keys = np.floor(points / size).astype(np.int64)
    keys -= column_min(keys)
    span = column_max(keys) + 1
    flat = np.ravel_multi_index(keys.T, span)
    _, voxel_of, counts = np.unique(flat, return_inverse=True, return_counts=True)
    centres = np.stack(
        [np.bincount(voxel_of, points[:, k]) / counts for k in range(points.shape[1])], axis=1
    )
    return voxel_of, centres


def least_voxels(options: SegmentOptions, voxel_m: float, at_3cm: int | None = None) -> int:
    """The fewest working voxels of ``voxel_m`` a cluster has (``at_3cm``, default
    ``min_points``, at 3 cm: the same surface in voxels of another size)."""
    return max(3, round((options.min_points if at_3cm is None else at_3cm) * (0.03 / voxel_m) ** 2))


def standing(
    points: NDArray, heights: NDArray, up: NDArray, walls: list[Plane], options: SegmentOptions,
    least: int | None = None,
) -> bool:  # fmt: skip
    """Whether a cluster (K, 3), its points' heights above the floor (K,), is an object's
    size and not a piece of a wall: enough points (``least``, default ``min_points``), tall
    enough, not larger than a room's furniture, not lying along a wall."""
    if len(points) < (options.min_points if least is None else least):
        return False
    if any(np.median(np.abs(w.distance(points))) < options.wall_piece_m for w in walls):
        return False
    top = float(percentiles(heights, [98])[0])
    if top < options.min_height_m or top - float(heights.min()) > options.max_size_m:
        return False
    flat = points - np.outer(points @ up, up)
    lo, hi = percentiles(flat, [1, 99])
    return float(np.linalg.norm(hi - lo)) <= options.max_size_m * math.sqrt(2)


def attach_pieces(
    points: NDArray, heights: NDArray, groups: list[NDArray[np.int64]], up: NDArray,
    options: SegmentOptions, weights: NDArray | None = None, floor_from: float | None = None,
    stands: Callable[[NDArray[np.int64]], bool] | None = None,
) -> list[NDArray[np.int64]]:  # fmt: skip
    """Clusters (indices into points (N, 3), heights (N,)) -> the ones standing on the floor,
    each with the pieces whose nearest point lies within ``attach_m`` of it. A cluster whose
    base is high stands all the same where it is nearer the camera (the origin), along the
    floor, than any floor the camera sees: its base is below the view (a level camera at head
    height sees the floor only from a few metres on): ``floor_from`` says how near, along the
    floor, the floor is seen (``nearest_floor``; default: from the points on the floor among
    ``points``). ``weights`` (N,): how many of the camera's points each point stands for.
    Where ``stands`` is given (an object's size, for a camera's view), each group of the
    pieces that no object takes stands as an object where ``stands`` keeps it and the floor
    under it is hidden (``HiddenFloor``: a headboard and the mattress before it, behind the
    ottoman at the bed's foot)."""
    if floor_from is None:  # the floor among the points
        floor_from = nearest_floor(points[np.abs(heights) <= options.floor_threshold_m], up)

    def whole(g: NDArray) -> bool:
        top = float(percentiles(heights[g], [98])[0])
        if top < options.min_object_m:
            return False
        if heights[g].min() <= options.max_base_m:
            return True
        lowest = g[np.argsort(heights[g])[: max(1, len(g) // 10)]]
        return float(np.median(np.linalg.norm(_footprint(points[lowest], up), axis=1))) < (
            floor_from
        )

    based = slivers_joined(points, [g for g in groups if whole(g)], options, weights, heights,
                           up)  # fmt: skip
    near = _Near(points, based)
    joined = [[g] for g in based]
    low, strays = [], []
    for piece in (g for g in groups if not whole(g)):
        gaps = near.gaps(piece, list(range(len(based))), options.attach_m)
        nearest = int(np.argmin(gaps)) if gaps else -1
        if nearest >= 0 and gaps[nearest] <= options.attach_m:
            joined[nearest].append(piece)
        elif heights[piece].min() <= options.max_base_m and _width(points[piece], up) >= (
            options.low_object_m
        ):
            low.append(piece)  # a low object of its own on the floor (a small tub, a low table)
        else:
            strays.append(piece)
    kept = []
    if stands is not None and strays:
        hidden = HiddenFloor(points, heights, up, options)
        kept = [g for g in _near_each_other(points, strays, options.attach_m)
                if stands(g) and hidden.under(g)]  # fmt: skip
    return [np.sort(np.concatenate(parts)) for parts in joined] + low + kept


def _near_each_other(
    points: NDArray, groups: list[NDArray[np.int64]], within: float
) -> list[NDArray[np.int64]]:
    """Clusters (indices into points (N, 3)) -> the unions of those that come ``within`` of
    each other (chains too)."""
    near = _Near(points, groups)
    pairs = [(i, j) for i in range(len(groups))
             for j, gap in enumerate(near.gaps(groups[i], list(range(i + 1, len(groups))), within),
                                     start=i + 1)
             if gap <= within]  # fmt: skip
    label = _components(len(groups), np.array(pairs, dtype=np.int64).reshape(-1, 2))
    return [np.sort(np.concatenate([groups[k] for k in np.flatnonzero(label == value)]))
            for value in np.unique(label)]  # fmt: skip


class HiddenFloor:
    """Whether the camera (the origin) does not see the floor under a cluster: the floor under
    most of its lowest points lies behind something nearer (a point within ``HIDDEN_RAY`` of the
    ray to it, ``attach_m`` or more nearer), and the cluster is an object's height (its top over
    ``min_object_m``, rising ``hidden_min_rise_m`` from its lowest point: a flat piece, the top
    of a table or a block seen past what stands before it, is no object of its own)."""

    def __init__(self, points: NDArray, heights: NDArray, up: NDArray, options: SegmentOptions):
        self.points, self.heights, self.up, self.options = points, heights, up, options
        self.ranges = np.linalg.norm(points, axis=1)
        self._directions: cKDTree | None = None  # built on first use

    def under(self, group: NDArray[np.int64]) -> bool:
        heights, options = self.heights[group], self.options
        top = float(percentiles(heights, [98])[0])
        if top < options.min_object_m or top - float(heights.min()) < options.hidden_min_rise_m:
            return False
        if self._directions is None:
            self._directions = cKDTree(self.points / np.maximum(self.ranges, 1e-9)[:, None])
        lowest = group[np.argsort(heights)[: max(1, len(group) // 10)]]
        below = self.points[lowest] - np.outer(self.heights[lowest], self.up)  # on the floor
        reach = np.linalg.norm(below, axis=1)
        rays = self._directions.query_ball_point(below / reach[:, None], HIDDEN_RAY)
        # the nearest point along each ray, all rays at once (a ray with none: infinitely far)
        counts = np.fromiter(map(len, rays), dtype=np.intp, count=len(rays))
        hits = np.fromiter(chain.from_iterable(rays), dtype=np.intp, count=int(counts.sum()))
        nearest = np.full(len(rays), np.inf)
        if len(hits):
            starts = np.cumsum(counts) - counts
            seen = counts > 0
            nearest[seen] = np.minimum.reduceat(self.ranges[hits], starts[seen])
        return bool(np.mean(nearest < reach - options.attach_m) > 0.5)


def _width(points: NDArray, up: NDArray) -> float:
    """A cluster's (K, 3) widest extent along the floor, metres (1st to 99th percentile)."""
    flat = _footprint(points, up)
    lo, hi = percentiles(flat, [1, 99])
    return float(np.linalg.norm(hi - lo))


def slivers_joined(
    points: NDArray, groups: list[NDArray[np.int64]], options: SegmentOptions,
    weights: NDArray | None = None, heights: NDArray | None = None, up: NDArray | None = None,
) -> list[NDArray[np.int64]]:  # fmt: skip
    """Standing clusters (indices into points (N, 3)) -> the same, each small one that lies
    within ``sliver_m`` of a cluster with at least 1 / ``sliver_share`` times its points, or
    within ``far_sliver_m`` of one with at least 1 / ``far_sliver_share`` times where (given
    ``up`` (3,)) it is no object standing beside that one (``_beside``), joined to the
    nearest such (smallest first, so a chain of pieces ends in its object), where its top rises
    at most ``sliver_rise_m`` over that one's (``heights`` (N,) over the floor; default: no
    such limit). ``weights`` (N,): how many of the camera's points each point stands for (a
    voxel's), else one each."""
    parts: list[list[NDArray[np.int64]] | None] = [[g] for g in groups]
    sizes = [len(g) if weights is None else float(weights[g].sum()) for g in groups]
    tops = [
        math.inf if heights is None else float(percentiles(heights[g], [98])[0]) for g in groups
    ]
    apart = _Near(points, groups)
    reach = max(options.sliver_m, options.far_sliver_m)
    for i in sorted(range(len(groups)), key=lambda k: sizes[k]):
        larger = [j for j in range(len(groups)) if sizes[i] <= options.sliver_share * sizes[j]
                  and tops[i] <= tops[j] + options.sliver_rise_m]  # fmt: skip
        if not larger:
            continue
        gaps = []
        for j, gap in zip(larger, apart.gaps(groups[i], larger, reach), strict=True):
            near = gap <= options.sliver_m or (
                gap <= options.far_sliver_m
                and sizes[i] <= options.far_sliver_share * sizes[j]
                and (up is None or not _beside(points[groups[i]], points[groups[j]], up,
                                               options))
            )  # fmt: skip
            gaps.append(gap if near else np.inf)
        nearest = int(np.argmin(gaps))
        if np.isfinite(gaps[nearest]):
            owner, mine = parts[larger[nearest]], parts[i]
            assert owner is not None and mine is not None  # larger ones are merged later
            owner.extend(mine)
            parts[i] = None
    return [np.sort(np.concatenate(p)) for p in parts if p is not None]


class _Near:
    """How near clusters come to some clusters (indices into points (N, 3)): their boxes first,
    and a KD-tree of a cluster's points only where its box is near enough."""

    def __init__(self, points: NDArray, groups: list[NDArray[np.int64]]) -> None:
        self.points, self.groups = points, groups
        self.lows = np.array([column_min(points[g]) for g in groups]).reshape(-1, 3)
        self.highs = np.array([column_max(points[g]) for g in groups]).reshape(-1, 3)
        self.trees: dict[int, cKDTree] = {}

    def gaps(self, piece: NDArray[np.int64], near: list[int], beyond: float) -> list[float]:
        """How near ``piece`` comes to each cluster of ``near`` (their places in the groups);
        infinite where their boxes lie farther than ``beyond`` apart (the boxes of all at once:
        a frame's pieces are many, most of a voxel or two)."""
        lo, hi = column_min(self.points[piece]), column_max(self.points[piece])
        which = np.asarray(near, dtype=np.intp)
        apart = np.maximum(0.0, np.maximum(self.lows[which] - hi, lo - self.highs[which]))
        far = np.sqrt(np.einsum("ij,ij->i", apart, apart)) > beyond
        out = []
        for j, skip in zip(near, far.tolist(), strict=True):
            if skip:
                out.append(math.inf)
                continue
            if j not in self.trees:
                self.trees[j] = cKDTree(self.points[self.groups[j]])
            out.append(_gap(self.points, piece, self.trees[j]))
        return out


def _gap(points: NDArray, piece: NDArray[np.int64], tree: cKDTree) -> float:
    """How near a cluster (indices into points (N, 3)) comes to the points of ``tree``, from
    about 200 of its points."""
    sample = points[piece[:: max(1, len(piece) // 200)]]
    return float(tree.query(sample, k=1)[0].min())


def _beside(piece: NDArray, owner: NDArray, up: NDArray, options: SegmentOptions) -> bool:
    """Whether a cluster (K, 3) is an object standing beside another (M, 3) rather than a piece
    of it: as wide as ``low_object_m`` along the floor, with less than ``far_sliver_within`` of
    its footprint within the other's grown by ``far_sliver_m``."""
    return (
        _width(piece, up) >= options.low_object_m
        and _within(piece, owner, up, options.far_sliver_m) < options.far_sliver_within
    )


def _within(piece: NDArray, owner: NDArray, up: NDArray, grow: float) -> float:
    """The share of a cluster's (K, 3) footprint that lies within another's (M, 3), the
    rectangle along that one's own axes on the floor (1st to 99th percentile) grown by
    ``grow`` a side."""
    flat = _footprint(owner, up)
    centre = flat.mean(axis=0)
    axes = np.linalg.svd(flat - centre, full_matrices=False)[2]  # (2, 2): its axes, as rows
    lo, hi = percentiles((flat - centre) @ axes.T, [1, 99])
    mine = (_footprint(piece, up) - centre) @ axes.T
    return float(np.mean(np.all((mine >= lo - grow) & (mine <= hi + grow), axis=1)))


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
    view: bool = True,
) -> Segmentation:
    """A scene cloud (N, 3) in the camera's frame, metres -> its Segmentation (see the
    module). ``expected_up``: roughly which way is up in the cloud (the floor is searched
    within ``max_tilt_deg`` of it). ``view``: the cloud is what one camera's view holds (its
    edges are the view's); off for a room's cloud looked at from the origin.

    The planes are found among voxels of ``plane_points`` of the points, the objects on a working
    cloud of what is neither floor nor wall (``VoxelCloud``, at most ``work_points`` voxels, from at
    most ``max_input`` points): the cost follows the room and the budget, not the camera's
    resolution; each object then gets every point of its voxels."""
    rng = np.random.default_rng(seed)
    edges = ViewEdges.of_points(points) if view else None
    prior = np.asarray(expected_up, dtype=np.float64)
    prior = prior / np.linalg.norm(prior)
    thinned = points[:: max(1, -(-len(points) // options.max_input))]
    planar = plane_sample(thinned, options)
    floor = find_floor(planar, prior, options, rng)
    if floor is None:
        return Segmentation(None, prior, edges=edges)
    # refitted to the frame's own points: voxel centroids where the floor meets an object lean
    # toward the object (where too few lie near it, as found)
    floor = refined_plane(floor, points, options.floor_threshold_m, rng) or floor
    up = floor.normal
    above = floor.distance(planar) > options.floor_threshold_m
    walls = find_walls(planar[above], up, floor, options, rng, edges)
    rest = thinned[off_planes(thinned, floor, walls, options)]
    if len(rest) == 0:
        return Segmentation(floor, up, walls, [], edges)
    cloud = VoxelCloud.of(rest, options.work_voxel_m, working_points_of(options))
    work = cloud.points
    heights = floor.distance(work)
    band = np.zeros(len(work), bool)
    for wall in walls:
        band |= wall.distance(work) <= options.wall_band_m
    groups = clusters(work, up, options, cloud.voxel_m, band)
    least = least_voxels(options, cloud.voxel_m)
    hidden_least = least_voxels(options, cloud.voxel_m, options.hidden_min_points)
    objects = [g for g in groups if standing(work[g], heights[g], up, walls, options, least)]
    floor_seen = planar[np.abs(floor.distance(planar)) <= options.floor_threshold_m]

    # pieces stand on a floor hidden from the camera only where a camera saw the cloud
    def stands(g: NDArray[np.int64]) -> bool:
        return standing(work[g], heights[g], up, walls, options, hidden_least)

    objects = attach_pieces(work, heights, objects, up, options, cloud.weights,
                            nearest_floor(floor_seen, up), stands if view else None)  # fmt: skip
    judge = load_cut_judge() if options.split_touching else None
    if judge is not None:
        objects = split_touching(work, objects, floor, judge)
    # each object's points at the camera's resolution: those of its voxels, off the planes (the
    # planes first: most of a frame is floor and wall, and looking a point up costs more)
    off = np.flatnonzero(off_planes(points, floor, walls, options))
    objects = [off[rows] for rows in cloud.spread(points[off], objects)]
    objects.sort(key=len, reverse=True)
    return Segmentation(floor, up, walls, objects, edges)


def plane_sample(points: NDArray, options: SegmentOptions) -> NDArray[np.float64]:
    """What the planes are found among: the centroids of voxels of ``plane_voxel_m`` of at most
    ``plane_points`` of the points (N, 3). Each stands for a piece of surface, not for the
    pixels a near surface fills and a far one does not."""
    sample = points[:: max(1, -(-len(points) // options.plane_points))]
    return VoxelCloud.of(sample, options.plane_voxel_m, len(sample)).points


def off_planes(
    points: NDArray, floor: Plane, walls: list[Plane], options: SegmentOptions
) -> NDArray[np.bool_]:
    """Which points (N, 3) are neither floor nor wall (N,)."""
    keep = floor.distance(points) > options.floor_threshold_m
    for wall in walls:
        keep &= wall.distance(points) > options.wall_threshold_m
    return keep


def nearest_floor(floor_points: NDArray, up: NDArray) -> float:
    """How near the camera (the origin), along the floor, the floor is seen: the 1st
    percentile of its points' (F, 3) distances; infinite where none is seen."""
    reach = np.linalg.norm(_footprint(floor_points, up), axis=1)
    return float(percentiles(reach, [1])[0]) if len(reach) else math.inf


# The objects' working cloud's size per ms of a scene's budget, within bounds. The cloud stops
# growing at 10,500 voxels (a budget of 140 ms; a real Kinect v2 bedroom's objects fill about
# 9,800 voxels of 4 cm, segmented in 110-150 ms on 2 cores, docs/scenes.md, "Cost"): what the
# fitted steps (the touching cut, the scene classifier) were fitted on, and what a larger budget
# buys goes to posing the objects, whose cost grows with their number, not to segmenting them
# finer.
WORK_POINTS_PER_MS = 75
# the floor under a point is hidden where a nearer point lies within this (the chord of about
# 1.5 degrees) of the ray to it
HIDDEN_RAY = 0.026
WORK_POINTS_RANGE = (4_000, 10_500)


def working_points(budget_ms: float) -> int:
    """How many voxels the objects of a scene of ``budget_ms`` are found in
    (``WORK_POINTS_PER_MS``)."""
    low, high = WORK_POINTS_RANGE
    return int(min(max(WORK_POINTS_PER_MS * budget_ms, low), high))


def working_points_of(options: SegmentOptions) -> int:
    """``options.work_points``, or where it is None the most (what every budget from 140 ms
    gets, the default's among them)."""
    return WORK_POINTS_RANGE[1] if options.work_points is None else options.work_points


@dataclass(frozen=True)
class VoxelCloud:
    """Points as the segmentation sees them: the centroids (V, 3) of voxels of ``voxel_m`` on
    a grid from ``origin``, their keys (V,) sorted, and how many points each holds (V,)."""

    points: NDArray[np.float64]
    weights: NDArray[np.float64]
    keys: NDArray[np.int64]
    origin: NDArray[np.float64]
    voxel_m: float

    @classmethod
    def of(cls, points: NDArray, voxel_m: float, most: int) -> VoxelCloud:
        """Points (N >= 1, 3) in voxels of ``voxel_m``, or larger ones where there would be
        more than ``most`` (a large room)."""
        origin = column_min(points)
        size = voxel_m
        keys, voxel_of = np.unique(_keys(points, size, origin), return_inverse=True)
        for _ in range(3):
            if len(keys) <= most:
                break
            size *= math.sqrt(len(keys) / most) * 1.05
            keys, voxel_of = np.unique(_keys(points, size, origin), return_inverse=True)
        counts = np.bincount(voxel_of, minlength=len(keys)).astype(np.float64)
        centres = np.stack([np.bincount(voxel_of, points[:, k], len(keys)) / counts
                            for k in range(3)], axis=1)  # fmt: skip
        return cls(centres, counts, keys, origin, size)

    def voxel_of(self, points: NDArray) -> NDArray[np.int64]:
        """Each point's (N, 3) voxel (N,), -1 where it falls in none."""
        every = _keys(points, self.voxel_m, self.origin)
        where = np.minimum(np.searchsorted(self.keys, every), len(self.keys) - 1)
        inside = self.keys[where] == every
        for k in range(3):
            inside &= points[:, k] >= self.origin[k]
        return np.where(inside, where, -1)

    def spread(self, points: NDArray, objects: list[NDArray[np.int64]]) -> list[NDArray[np.int64]]:
        """Objects found on the voxels (their indices) -> the indices of the ``points`` (N, 3)
        that fall in their voxels."""
        label = np.full(len(self.keys) + 1, -1)
        for k, rows in enumerate(objects):
            label[rows] = k
        owner = label[self.voxel_of(points)]  # no voxel (-1): the last entry, -1
        index = np.flatnonzero(owner >= 0)
        owner = owner[index]
        return [index[owner == k] for k in range(len(objects))]


def _keys(points: NDArray, size: float, origin: NDArray) -> NDArray[np.int64]:
    """Points (N, 3) -> one integer key (N,) per voxel of ``size`` on a grid from ``origin``
    (21 bits a coordinate: 60 km at 3 cm; a point below ``origin`` gets a key of its own
    that no voxel has), a column at a time."""
    keys = np.zeros(len(points), dtype=np.int64)
    for k, shift in enumerate((42, 21, 0)):
        cells = np.floor((points[:, k] - origin[k]) * (1.0 / size)).astype(np.int64)
        keys |= (cells & 0x1FFFFF) << shift
    return keys
