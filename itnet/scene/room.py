"""A room's cloud as well as a camera's view: a fused reconstruction (a SLAM map, a scan of a
room) has no camera at its origin, and its origin may lie anywhere (on the floor, in a corner).

A camera's view is segmented from the camera (``itnet.scene.segment``: the floor's normal
toward it, walls facing it, what the view hides). A room's cloud is segmented the same way from
a lookout of its own: its floor is found by the up direction alone (``floor_by_up``: the
largest plane within ``max_tilt_deg`` of up with nothing below it, its normal on up's side),
then what lies below ``CEILING_CUT_M`` over it (no ceiling) is looked at from ``LOOKOUT_M``
above the floor over its median point, as a camera there would see it (the viewpoint of the
objects' naming and poses), with no view edges (no object's base lies below a view) and up to
``ROOM_WALLS`` walls all round.

Which of the two a cloud is (``segment_scene``): a depth image is a camera's view; a cloud is
a room's where it is asked, or where it is not one camera's view (``looks_like_a_view``: its
points lie all round the origin), or where a camera at its origin would stand on or below its
floor.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from itnet.planes import Plane, ransac_plane, refined_plane
from itnet.scene.segment import Segmentation, SegmentOptions, plane_sample, segment

# a depth camera's view: every point within this of the view's mean direction (a wide one,
# 90 x 70 degrees, reaches 55 degrees at its corners)
VIEW_HALF_ANGLE_DEG = 75.0
VIEW_OUTSIDE_SHARE = 0.01  # ... but for this share of the points (flying pixels, noise)
MIN_CAMERA_HEIGHT_M = 0.2  # a camera at the origin stands at least this high over its floor
LOOKOUT_M = 1.5  # a room's cloud is looked at from this high over its floor
# what a room's cloud holds higher than this over its floor is none of the categories (a
# wardrobe stands 2.0 m): its ceiling and what hangs from it are left out
CEILING_CUT_M = 2.3
ROOM_WALLS = 6  # the walls a room's cloud may hold all round it (a view sees at most three)


def looks_like_a_view(points: NDArray) -> bool:
    """Whether a cloud (N, 3) could be one camera's view from the origin: all but
    ``VIEW_OUTSIDE_SHARE`` of its points lie within ``VIEW_HALF_ANGLE_DEG`` of their mean
    direction from it."""
    sample = np.asarray(points[:: max(1, len(points) // 20_000)], dtype=np.float64)
    ranges = np.linalg.norm(sample, axis=1)
    directions = sample[ranges > 1e-6] / ranges[ranges > 1e-6, None]
    if not len(directions):
        return False
    mean = directions.mean(0)
    if np.linalg.norm(mean) < 1e-6:
        return False
    cosines = directions @ (mean / np.linalg.norm(mean))
    outside = np.count_nonzero(cosines < math.cos(math.radians(VIEW_HALF_ANGLE_DEG)))
    return bool(outside <= VIEW_OUTSIDE_SHARE * len(directions))


def floor_by_up(
    points: NDArray, expected_up: NDArray, options: SegmentOptions, rng: np.random.Generator
) -> Plane | None:
    """The floor of a cloud (N, 3) wherever its origin lies: the largest plane within
    ``max_tilt_deg`` of ``expected_up`` (3,, unit) with nothing below it, its normal on up's
    side; None where there is none, or where most of the cloud lies below it (a ceiling)."""
    cos_tilt = math.cos(math.radians(options.max_tilt_deg))
    found = ransac_plane(
        points, rng, options.floor_threshold_m, lambda n: np.abs(n @ expected_up) > cos_tilt,
        hypotheses=options.floor_hypotheses, beyond_m=options.floor_beyond_m,
        local=options.floor_hypotheses // 2, toward=expected_up,
    )  # fmt: skip
    if found is None:
        return None
    plane = found[0].toward(expected_up)
    heights = plane.distance(points)
    threshold = options.floor_threshold_m
    if np.count_nonzero(heights < -threshold) > np.count_nonzero(heights > threshold):
        return None
    return plane


def segment_room(
    points: NDArray, options: SegmentOptions = SegmentOptions(),
    expected_up: NDArray | tuple[float, float, float] = (0.0, 0.0, 1.0), seed: int = 0,
) -> Segmentation:  # fmt: skip
    """A room's cloud (N, 3), metres, in any frame with ``expected_up`` roughly its up ->
    its Segmentation, looked at from ``LOOKOUT_M`` over its floor (see the module): its planes
    and viewpoint (the lookout) in the cloud's frame, no view edges."""
    prior = np.asarray(expected_up, dtype=np.float64)
    prior = prior / np.linalg.norm(prior)
    rng = np.random.default_rng(seed)
    thinned = points[:: max(1, -(-len(points) // options.max_input))]
    floor = floor_by_up(plane_sample(thinned, options), prior, options, rng)
    if floor is None:
        return Segmentation(None, prior, room=True)
    floor = refined_plane(floor, points, options.floor_threshold_m, rng) or floor
    below = np.flatnonzero(floor.distance(points) < CEILING_CUT_M)  # no ceiling, no lamps on it
    centre = np.median(thinned, axis=0)
    lookout = centre - (floor.distance(centre[None])[0] - LOOKOUT_M) * floor.normal
    walls_all_round = replace(options, max_walls=max(options.max_walls, ROOM_WALLS))
    seen = segment(points[below] - lookout, walls_all_round, floor.normal, seed, view=False)

    def back(plane: Plane) -> Plane:  # n . (p - lookout) + d = 0, in the cloud's frame
        return Plane(plane.normal, plane.offset - float(plane.normal @ lookout))

    return Segmentation(
        None if seen.floor is None else back(seen.floor), seen.up,
        [back(w) for w in seen.walls], [below[rows] for rows in seen.objects], None, lookout,
        True,
    )  # fmt: skip


def segment_scene(
    points: NDArray, options: SegmentOptions, expected_up: NDArray, room: bool | None = None,
    image: bool = False, seed: int = 0,
) -> Segmentation:  # fmt: skip
    """A scene's cloud (N, 3) -> its Segmentation, as a camera's view or as a room's (see the
    module). ``room``: True, a room's; False, a camera's view from the origin; None, decided
    from the cloud. ``image``: the cloud is a depth image's (a camera's view: ValueError where
    ``room`` is True)."""
    if image:
        if room:
            raise ValueError("room: a depth image is one camera's view, not a room's cloud")
        return segment(points, options, expected_up, seed)
    if room or (room is None and not looks_like_a_view(points)):
        return segment_room(points, options, expected_up, seed)
    found = segment(points, options, expected_up, seed)
    if room is None and (found.floor is None or found.floor.offset < MIN_CAMERA_HEIGHT_M):
        # a camera at the origin would stand on or below the floor up finds: a room's
        rooms = segment_room(points, options, expected_up, seed)
        if rooms.floor is not None and rooms.floor.offset < MIN_CAMERA_HEIGHT_M:
            return rooms
    return found
