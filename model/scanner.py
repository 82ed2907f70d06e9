"""Virtual depth-camera scans: what one viewpoint sees of a complete canonical shape.

Camera frame (OpenCV): x right, y down, z forward along the optical axis. A scan is expressed in
the camera frame and labelled with ``T_canonical_from_input`` (= inverse of the camera pose that
maps canonical points into the camera).

Two scanners:

* ``zbuffer_scan``: for point sets, z-buffer projection. Points are projected into a pixel grid;
  a point is kept when it is within ``tolerance`` of the nearest depth in its own pixel AND
  within ``occlusion_tolerance`` of the nearest depth in its 3x3 neighbourhood. The second test
  stops far surfaces from showing through the holes between the projected points of a near
  surface (a 1,024-point shape leaves most pixels empty); its larger slack keeps sloped surfaces
  up to ~60 degrees. These "occluded" views (the defaults) are what the product is measured on.
  ``PAPER_VIEWS`` is the paper's rule, the nearest point per pixel and nothing else: on sparse
  point sets a good part of the far side shows through, so those views are easier.
  ``SURFACE_VIEWS`` (``splat`` > 0) see each point as a small oriented disc and z-buffer the
  discs exactly (``model/surface.py``): the point set behaves like the surface it was sampled
  from, as a depth camera sees a mesh.
* ``raycast_scan``: for meshes, open3d ray casting through a pinhole camera.

Real cameras (``ScanConfig.sensor``, ``model/sensor.py``): the object is given a real size
(``radius_m``, drawn per scan: ``model.categories.REAL_RADIUS_M`` for each category), the camera
stands ``distance_m`` metres from it, and the camera's effects (noise, quantisation, dropouts,
holes, flying pixels) are applied in metres before the scan goes back to object radii. The
generic noise (``depth_noise``, ``jitter``) is then left out: the sensor model is the noise.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from itnet.geometry import (
    apply_rigid,
    axis_angle_to_matrix,
    invert_rigid,
    random_rotation,
    rigid_from_rotation_translation,
)
from itnet.model.shapes import Shape
from itnet.model.surface import splat_visible, surface_discs
from itnet.model.surroundings import Surroundings
from itnet.upright import rotation_onto


@dataclass(frozen=True)
class ScanConfig:
    """Ranges the viewpoints and sensor effects are drawn from (object radius = 1)."""

    distance: tuple[float, float] = (1.8, 4.0)  # camera to object centre
    off_axis: float = 0.25  # object centre off the optical axis, as a fraction of the distance
    pixel: tuple[float, float] = (0.035, 0.07)  # z-buffer pixel size at the object's distance
    tolerance: float = 0.08  # z-buffer: depth slack behind the nearest point of the same pixel
    occlusion_tolerance: float = 0.3  # ... and behind the nearest point of the 3x3 neighbourhood
    depth_noise: tuple[float, float] = (0.0, 0.01)  # sigma along the ray, per unit of distance
    jitter: tuple[float, float] = (0.0, 0.005)  # isotropic sigma
    outlier_fraction: tuple[float, float] = (0.0, 0.01)
    raycast_resolution: tuple[int, int] = (96, 160)  # image width range for mesh ray casting
    min_points: int = 64
    splat: float = 0.0  # > 0: points are discs this many local spacings wide (SURFACE_VIEWS)
    # (min, max) degrees: the camera's elevation over the shape's horizon (canonical +y up), its
    # azimuth and roll free, as a camera held above the floor sees furniture; None: any direction.
    # Left out of the repr, so the caches of views from any direction keep their keys.
    elevation: tuple[float, float] | None = field(default=None, repr=False)
    # (min, max) object radii: the object's base below the view (``below_view_edge``): what a
    # level camera does not see under the bottom edge of its view, a level plane across the view
    # through the camera and through the object's centre line at this height over its centre.
    # Left out of the repr, as ``elevation``.
    cut_below: tuple[float, float] | None = field(default=None, repr=False)
    # a depth camera's effects (``model.sensor.SENSORS``), in metres: the object ``radius_m``
    # metres in bounding radius (drawn per scan), the camera ``distance_m`` metres away
    sensor: str = "clean"
    radius_m: tuple[float, float] = (0.5, 0.5)
    distance_m: tuple[float, float] = (1.0, 6.0)
    # what a crop out of a room keeps beside the object (``model.surroundings``; its sizes in
    # metres under a sensor model, in object radii without); None: the object alone. Left out
    # of the repr, as ``elevation``.
    surroundings: Surroundings | None = field(default=None, repr=False)


PAPER_VIEWS: dict[str, object] = {
    "pixel": (0.045, 0.075),
    "tolerance": 0.0,
    "occlusion_tolerance": float("inf"),
}
"""ScanConfig overrides for the paper's z-buffer rule (the nearest point of each pixel)."""

SURFACE_VIEWS: dict[str, object] = {"splat": 1.0, "tolerance": 0.03}
"""ScanConfig overrides for surface views: each point a disc as wide as the local spacing, seen
when within 0.03 radii of the nearest disc at its pixel (``model/surface.py``)."""

BASE_HIDDEN: dict[str, object] = {"cut_below": (-0.7, 0.3), "elevation": (5.0, 40.0)}
"""ScanConfig overrides for views whose lower part lies below the view: a camera 5-40 degrees
above the object's horizon (one at head height, 2-4 m from furniture) whose view's bottom edge
passes 0.7 radii below to 0.3 above the object's centre (``below_view_edge``)."""

VIEW_RULES: dict[str, dict[str, object]] = {
    "occluded": {},
    "paper": PAPER_VIEWS,
    "surface": SURFACE_VIEWS,
    "base_hidden": BASE_HIDDEN,
}
"""The named view rules (``--scanner``) and their ScanConfig overrides."""


def sensor_views(sensor: str, radius_m: tuple[float, float]) -> dict[str, object]:
    """ScanConfig overrides for views by the camera ``sensor`` (``model.sensor.SENSORS``) of an
    object ``radius_m`` metres in bounding radius."""
    from itnet.model.sensor import SENSORS

    if sensor not in SENSORS:
        raise ValueError(f"unknown sensor {sensor!r} (known: {', '.join(SENSORS)})")
    return {"sensor": sensor, "radius_m": tuple(radius_m)}


CROP = "crop"
"""The suffix of a view rule's name for views cut out of a room (``occluded+kinect_v2+crop``)."""
CLUTTER = "clutter"
"""The suffix for views cut out of a furnished room (``occluded+kinect_v2+clutter``): a crop
whose piece most often carries things on its top (a lamp, books, a vase, a mirror)."""
ROOM_CUTS: dict[str, dict[str, object]] = {CROP: {}, CLUTTER: {"on_top": 0.8}}
"""The ``Surroundings`` overrides of each cut out of a room, by its suffix."""
CROP_ELEVATION = (-10.0, 55.0)
"""Where the camera of a crop out of a room stands unless told (degrees over the object's
horizon): above the floor, which would hide the object from below."""


def view_name_parts(name: str) -> tuple[str, str, str]:
    """A view rule's name -> (rule, sensor or '', the cut out of a room or ''): ``RULE``,
    ``RULE+SENSOR``, ``RULE+SENSOR+crop`` or ``RULE+SENSOR+clutter`` (``ROOM_CUTS``). Raises
    ValueError for an unknown rule or camera, or a crop without a camera (its surroundings have
    sizes in metres)."""
    from itnet.model.sensor import SENSORS

    rule, *rest = name.split("+")
    crop = rest[-1] if rest[-1:] and rest[-1] in ROOM_CUTS else ""
    sensor = "+".join(rest[:-1] if crop else rest)
    if rule not in VIEW_RULES:
        raise ValueError(f"unknown view rule {rule!r} (known: {', '.join(VIEW_RULES)})")
    if sensor and sensor not in SENSORS:
        raise ValueError(f"unknown sensor {sensor!r} (known: {', '.join(SENSORS)})")
    if crop and not sensor:
        raise ValueError(f"{name!r}: a crop out of a room needs a camera (RULE+SENSOR+{crop})")
    return rule, sensor, crop


def named_overrides(name: str, category: str) -> dict[str, object]:
    """The ScanConfig overrides of a named view rule, seen by a named camera where the name says
    so: ``RULE``, ``RULE+SENSOR`` (``occluded+kinect_v2``: occluded views of a real-sized
    piece of ``category`` by a Kinect v2) or ``RULE+SENSOR+crop`` (the same, cut out of a room
    by the object's box: ``model.surroundings``; ``+clutter``: things stand on the piece)."""
    from itnet.model.categories import real_radius_m

    rule, sensor, crop = view_name_parts(name)
    camera = sensor_views(sensor, real_radius_m(category)) if sensor else {}
    return {**VIEW_RULES[rule], **camera, **({"surroundings": room_cut(crop)} if crop else {})}


def room_cut(suffix: str) -> bool | dict[str, object]:
    """A cut's ``surroundings`` setting as a JSON config stores it: False for no cut (''),
    True (the default ``Surroundings``) or its overrides."""
    return bool(suffix) and (ROOM_CUTS[suffix] or True)


def named_views(name: str, category: str) -> ScanConfig:
    """The ScanConfig of ``named_overrides``."""
    return scan_config(named_overrides(name, category))


def scan_config(*overrides: Mapping[str, Any]) -> ScanConfig:
    """The default ScanConfig with each mapping of ``overrides`` applied in turn. Lists become
    tuples: overrides stored in a JSON config come back as lists; ``surroundings`` may be a
    bool (True: the default ``Surroundings``) or a mapping of its overrides, and a view with
    surroundings is seen from ``CROP_ELEVATION`` unless an elevation is given."""
    merged = {k: tuple(v) if isinstance(v, list) else v for o in overrides for k, v in o.items()}
    cut = merged.get("surroundings")
    if isinstance(cut, bool):  # as a rule's name or a JSON config says it
        merged["surroundings"] = Surroundings() if cut else None
    elif isinstance(cut, Mapping):
        merged["surroundings"] = Surroundings(
            **{k: tuple(v) if isinstance(v, list) else v for k, v in cut.items()}
        )
    if merged.get("surroundings") is not None and merged.get("elevation") is None:
        merged["elevation"] = CROP_ELEVATION
    return replace(ScanConfig(), **merged)


def random_camera_pose(rng: np.random.Generator, config: ScanConfig) -> NDArray[np.float64]:
    """T_camera_from_canonical: a random rotation (any, or from ``config.elevation``), random
    distance and offset of the object from the optical axis."""
    distance = rng.uniform(*config.distance)
    offset = rng.uniform(-config.off_axis, config.off_axis, size=2) * distance
    centre = np.array([*offset, distance])  # the object's centre in the camera frame
    if config.elevation is None:
        return rigid_from_rotation_translation(random_rotation(rng), centre)
    looking = camera_from_canonical_looking_at(
        np.radians(rng.uniform(*config.elevation)),
        rng.uniform(-np.pi, np.pi),
        rng.uniform(-np.pi, np.pi),
    )  # the centre on the optical axis; then turned, about the camera, to where it is seen
    seen_at = rotation_onto([0.0, 0.0, 1.0], centre / np.linalg.norm(centre))
    return rigid_from_rotation_translation(seen_at @ looking, centre)


def camera_from_canonical_looking_at(
    elevation: float, azimuth: float, roll: float
) -> NDArray[np.float64]:
    """R_camera_from_canonical (3, 3) of a camera at ``elevation`` radians over the canonical
    horizon (+y up) and ``azimuth`` about +y (0: on +z), looking at the origin, turned by
    ``roll`` about its optical axis (0: its x axis horizontal, y down)."""
    position = np.array(
        [
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
            np.cos(elevation) * np.cos(azimuth),
        ]
    )
    forward = -position
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)  # |elevation| < 90 degrees: forward is never vertical
    level = np.stack([right, np.cross(forward, right), forward])  # rows: camera x, y, z
    return axis_angle_to_matrix([0.0, 0.0, 1.0], roll) @ level


def zbuffer_visible(
    camera_points: NDArray, pixel: float, tolerance: float, occlusion_tolerance: float
) -> NDArray[np.bool_]:
    """Visibility mask (M,) of camera-frame points (M, 3) under a z-buffer (see module doc)."""
    z = camera_points[:, 2]
    angular = pixel / np.median(z)
    uv = np.floor(camera_points[:, :2] / z[:, None] / angular).astype(np.int64)
    uv -= uv.min(0) - 1  # one pixel of margin for the neighbourhood
    h, w = uv.max(0) + 2
    zbuf = np.full((h, w), np.inf)
    np.minimum.at(zbuf, (uv[:, 0], uv[:, 1]), z)
    near = zbuf.copy()
    for du in (-1, 0, 1):
        for dv in (-1, 0, 1):
            near[1:-1, 1:-1] = np.minimum(
                near[1:-1, 1:-1], zbuf[1 + du : h - 1 + du, 1 + dv : w - 1 + dv]
            )
    own, neighbourhood = zbuf[uv[:, 0], uv[:, 1]], near[uv[:, 0], uv[:, 1]]
    return (z <= own + tolerance) & (z <= neighbourhood + occlusion_tolerance)


def add_sensor_effects(
    camera_points: NDArray, rng: np.random.Generator, config: ScanConfig
) -> NDArray[np.float64]:
    """Depth noise along each ray, isotropic jitter (both left out under a sensor model, which
    is the noise), and a few outliers near the object."""
    p = camera_points.copy()
    if config.sensor == "clean":
        depth = np.linalg.norm(p, axis=1, keepdims=True)
        sigma = rng.uniform(*config.depth_noise) * depth
        p *= 1 + sigma * rng.normal(size=(len(p), 1)) / depth
        p += rng.normal(scale=rng.uniform(*config.jitter), size=p.shape)
    n_out = int(rng.uniform(*config.outlier_fraction) * len(p))
    if n_out:
        lo, hi = p.min(0), p.max(0)
        p[rng.choice(len(p), n_out, replace=False)] = rng.uniform(lo, hi, size=(n_out, 3))
    return p


def zbuffer_scan(
    points: NDArray,
    camera_from_canonical: NDArray,
    pixel: float,
    tolerance: float = 0.08,
    occlusion_tolerance: float = 0.3,
) -> NDArray[np.float64]:
    """Canonical points (M, 3) -> the visible ones in the camera frame (K, 3)."""
    camera_points = apply_rigid(camera_from_canonical, points)
    return camera_points[zbuffer_visible(camera_points, pixel, tolerance, occlusion_tolerance)]


def raycast_scan(
    vertices: NDArray, triangles: NDArray, camera_from_canonical: NDArray, width: int
) -> NDArray[np.float64]:
    """Mesh (V, 3), (F, 3) in canonical -> ray hits in the camera frame (K, 3), pinhole camera.

    The field of view is fitted to the unit sphere at the camera's distance, with ``width``
    pixels across.
    """
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    camera_vertices = apply_rigid(camera_from_canonical, vertices).astype(np.float32)
    scene.add_triangles(camera_vertices, np.asarray(triangles, dtype=np.uint32))
    centre = camera_from_canonical[:3, 3]
    half = (np.abs(centre[:2]).max() + 1.05) / centre[2]  # tan of the half field of view
    axis = np.linspace(-half, half, width)
    u, v = np.meshgrid(axis, axis)
    directions = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    rays = np.concatenate([np.zeros_like(directions), directions], 1).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    ok = np.isfinite(hit)
    return directions[ok] * hit[ok, None]


def surfel_scan(
    points: NDArray,
    discs: tuple[NDArray, NDArray],
    camera_from_canonical: NDArray,
    pixel: float,
    splat: float,
    tolerance: float,
) -> NDArray[np.float64]:
    """Canonical points (M, 3) with their ``surface_discs`` (normals (M, 3), spacing (M,)) ->
    the visible ones in the camera frame (K, 3), each point a disc ``splat`` spacings wide."""
    camera_points = apply_rigid(camera_from_canonical, points)
    camera_normals = discs[0] @ camera_from_canonical[:3, :3].T
    seen = splat_visible(camera_points, camera_normals, splat * discs[1], pixel, tolerance)
    return camera_points[seen]


def scan_shape(
    points: NDArray,
    rng: np.random.Generator,
    config: ScanConfig,
    triangles: NDArray | None = None,
    discs: tuple[NDArray, NDArray] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One random partial scan of a canonical shape -> (camera-frame points (K, 3),
    T_canonical_from_input (4, 4)). Retries viewpoints until at least ``min_points`` are seen.
    ``discs``: the points' ``surface_discs`` for surface views and surroundings (computed here
    when not given)."""
    radius_m = 1.0
    if config.sensor != "clean":  # a real size and distance: the camera's effects are in metres
        radius_m = rng.uniform(*config.radius_m)
        distance = (config.distance_m[0] / radius_m, config.distance_m[1] / radius_m)
        # in object radii; a camera closer than 1.3 radii would stand inside the piece's box
        config = replace(config, distance=(max(distance[0], 1.3), max(distance[1], 1.4)))
    whole = points
    if config.surroundings is not None:
        if triangles is not None:
            raise ValueError("surroundings are added to point sets, not to meshes")
        discs = surface_discs(points) if discs is None else discs
        points, discs, boxed = _surrounded(points, discs, config.surroundings, radius_m, rng)
        whole = points[:boxed]  # the shape, and what stands on it where the crop holds that
    if config.splat <= 0 or triangles is not None:
        discs = None
    elif discs is None:
        discs = surface_discs(points)
    for _ in range(20):
        camera_from_canonical = random_camera_pose(rng, config)
        if config.surroundings is not None:  # a floor may reach past the camera
            seen = _seen_in_range(points, discs, camera_from_canonical, rng, config, radius_m)
        else:
            seen = _seen(points, triangles, discs, camera_from_canonical, rng, config)
        if config.cut_below is not None:
            height = rng.uniform(*config.cut_below)
            seen = seen[below_view_edge(seen, camera_from_canonical, height)]
        if config.sensor != "clean" and len(seen) >= config.min_points:
            seen = sensed(seen, rng, config, radius_m)
        if config.surroundings is not None:
            canonical = apply_rigid(invert_rigid(camera_from_canonical), seen)
            seen = seen[config.surroundings.crop(canonical, whole, radius_m, rng)]
        if len(seen) >= config.min_points:
            return add_sensor_effects(seen, rng, config), invert_rigid(camera_from_canonical)
    raise ValueError("no viewpoint saw enough of the shape")


def _surrounded(
    points: NDArray, discs: tuple[NDArray, NDArray], surroundings: Surroundings,
    radius_m: float, rng: np.random.Generator,
) -> tuple[NDArray[np.float64], tuple[NDArray, NDArray], int]:  # fmt: skip
    """A shape's points (M, 3) and discs with ``surroundings`` added (the shape's rows first),
    and how many first rows the crop's box is drawn around (``Surroundings.around``)."""
    spacing = float(np.median(discs[1]))
    surrounded, normals, boxed = surroundings.around(points, spacing, radius_m, rng)
    added = len(surrounded) - len(points)
    return (
        surrounded,
        (
            np.concatenate([discs[0], normals]),
            np.concatenate([discs[1], np.full(added, spacing)]),
        ),
        boxed,
    )


NEAREST_M = 0.4
"""A depth camera's nearest range (the Kinect v2's 0.5 m, a RealSense's less): what is nearer,
or behind it, a crop's surroundings leave out."""


def _seen_in_range(
    points: NDArray, discs: tuple[NDArray, NDArray] | None, camera_from_canonical: NDArray,
    rng: np.random.Generator, config: ScanConfig, radius_m: float,
) -> NDArray[np.float64]:  # fmt: skip
    """``_seen`` of the points (M, 3) at least ``NEAREST_M`` ahead of the camera."""
    depth = points @ camera_from_canonical[2, :3] + camera_from_canonical[2, 3]
    ahead = depth > NEAREST_M / radius_m
    if discs is not None:
        discs = (discs[0][ahead], discs[1][ahead])
    return _seen(points[ahead], None, discs, camera_from_canonical, rng, config)


def _seen(
    points: NDArray, triangles: NDArray | None, discs: tuple[NDArray, NDArray] | None,
    camera_from_canonical: NDArray, rng: np.random.Generator, config: ScanConfig,
) -> NDArray[np.float64]:  # fmt: skip
    """What the camera at ``camera_from_canonical`` sees of the shape, by the scanner its
    kind asks for: rays on a mesh, discs for surface views, else the z-buffer of points."""
    if triangles is not None:
        width = int(rng.integers(*config.raycast_resolution))
        return raycast_scan(points, triangles, camera_from_canonical, width)
    if discs is not None:
        pixel = rng.uniform(*config.pixel)
        return surfel_scan(
            points, discs, camera_from_canonical, pixel, config.splat, config.tolerance
        )
    return zbuffer_scan(
        points,
        camera_from_canonical,
        rng.uniform(*config.pixel),
        config.tolerance,
        config.occlusion_tolerance,
    )


def sensed(seen: NDArray, rng: np.random.Generator, config: ScanConfig,
           radius_m: float) -> NDArray[np.float64]:  # fmt: skip
    """A scan (K, 3) in object radii, camera frame -> what ``config.sensor`` returns of it, in
    object radii (the object ``radius_m`` metres in radius)."""
    from itnet.model.sensor import SENSORS

    return SENSORS[config.sensor].apply(seen * radius_m, rng) / radius_m


def below_view_edge(
    seen: NDArray, camera_from_canonical: NDArray, height: float
) -> NDArray[np.bool_]:
    """Camera-frame points (K, 3) of a canonical shape seen from ``camera_from_canonical``
    (4, 4) -> which of them (K,) lie above the bottom edge of a level view: the plane through
    the camera, level across the view (perpendicular to up, canonical +y, and to the direction
    of the object's centre) and through the point ``height`` (object radii) above the centre."""
    up = camera_from_canonical[:3, 1]
    centre = camera_from_canonical[:3, 3]
    across = np.cross(up, centre)
    normal = np.cross(across, centre + height * up)
    if normal @ up < 0:
        normal = -normal
    return np.asarray(seen @ normal >= 0.0)


def scan_of(
    shape: Shape, rng: np.random.Generator, config: ScanConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``scan_shape`` of a Shape: its mesh when it has one, its kept surface discs for surface
    views and surroundings."""
    wants_discs = config.splat > 0 or config.surroundings is not None
    discs = shape.discs() if wants_discs and shape.triangles is None else None
    return scan_shape(shape.points, rng, config, shape.triangles, discs)
