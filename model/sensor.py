"""What a depth camera does to what it sees: the sensor model of virtual scans.

A scan from ``model.scanner`` is the set of an object's surface points a viewpoint sees, exact.
A depth camera returns less, and worse. ``SensorModel.apply`` turns such a scan, in metres in
the camera frame (x right, y down, z ahead), into what a given camera would return:

* **no return** at grazing incidence (the surface's angle to the ray past ``max_angle_deg``)
  and far away (returns fade out over ``fade_m``);
* **holes**: patches of the surface that return nothing (dark, shiny or thin parts, IR shadow);
* **axial noise** growing with depth and with the angle to the surface, ``sigma_z(z, theta) =
  a + b (z - z0)^2 + s z^2 / (f B) + c theta^2 / (pi/2 - theta)^2 / sqrt(z)`` (the first, second
  and last terms Nguyen, Izadi and Lovell's fit for the Kinect, 3DIMPVT 2012; the third, the
  RMS error of active stereo, Intel's D400 depth-quality white paper); **lateral noise**
  ``lateral_px`` pixels;
* **quantisation**: of disparity (structured light and stereo: ``disparity_step_px`` of
  ``f B / z``) and of the depth image's unit (1 mm);
* **flying pixels** at the silhouette: mixed returns of the object and what lies behind it,
  along the ray (time-of-flight cameras most);
* **misregistration**: the whole scan shifted a little (depth-to-body calibration).

The presets (``SENSORS``) take their numbers from the cameras' published characterisations
(docs/training.md, "Sensor models", cites them): ``kinect_v1`` (structured light),
``kinect_v2`` (time of flight), ``realsense_d435`` (active stereo), and ``clean`` (an exact
render: nothing done). ``SensorModel.apply_to_depth`` does the same to a rendered depth image
(the development scenes'). Pure numpy and scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class SensorModel:
    """A depth camera's effects (distances in metres, angles in degrees; see the module)."""

    name: str
    focal_px: float = 525.0  # at its native depth resolution
    axial: tuple[float, float, float] = (0.0, 0.0, 0.0)  # a, b, z0 of sigma_z (m, 1/m, m)
    angle_term: float = 0.0  # c of sigma_z (m^1.5)
    stereo_subpixel: float = 0.0  # s: RMS subpixel error of stereo matching (px)
    baseline_m: float = 0.0  # B: projector-camera or stereo baseline (0: time of flight)
    lateral_px: float = 0.0
    disparity_step_px: float = 0.0  # 0: no disparity quantisation
    depth_unit_m: float = 0.0  # 0: no depth quantisation
    max_angle_deg: float = 90.0  # no return beyond (a 10-degree ramp up to it)
    fade_m: tuple[float, float] = (math.inf, math.inf)  # returns fade out from ... to ...
    holes: tuple[int, int] = (0, 0)  # how many missing patches (uniform, inclusive)
    hole_radius_m: tuple[float, float] = (0.03, 0.12)
    flying_share: float = 0.0  # share of the silhouette's points that fly
    # ... pushed back this far along the ray: the ones a segmenter leaves on the object (those
    # further back part from it, with the background)
    flying_depth_m: tuple[float, float] = (0.02, 0.25)
    misregistration_m: float = 0.0  # sigma of the whole scan's shift

    @property
    def clean(self) -> bool:
        return self == SensorModel(self.name)

    def sigma_z(self, z: NDArray, theta: NDArray) -> NDArray[np.float64]:
        """Axial noise sigma (m) at depth ``z`` (m) and incidence ``theta`` (rad), both (K,)."""
        a, b, z0 = self.axial
        sigma = a + b * (z - z0) ** 2
        if self.baseline_m > 0 and self.stereo_subpixel > 0:
            sigma = sigma + self.stereo_subpixel * z**2 / (self.focal_px * self.baseline_m)
        if self.angle_term > 0:
            theta = np.minimum(theta, np.radians(85.0))
            sigma = sigma + self.angle_term * theta**2 / (np.pi / 2 - theta) ** 2 / np.sqrt(z)
        return np.asarray(sigma, dtype=np.float64)

    def apply(self, points: NDArray, rng: np.random.Generator) -> NDArray[np.float64]:
        """A scan (K, 3), camera frame, metres -> what the camera returns of it (K', 3), K' <= K
        (the flying pixels moved, not added; possibly none). Fewer than 8 points come back as
        they are."""
        p = np.asarray(points, dtype=np.float64)
        if self.clean or len(p) < 8:
            return p.copy()
        tree = cKDTree(p)
        theta = incidence(p, tree)
        keep = self._returns(p, theta, rng) & ~self._holes(p, tree, rng)
        if keep.sum() < 8:  # the holes took almost everything: leave them out
            keep = self._returns(p, theta, rng)
        p, theta = p[keep], theta[keep]
        if len(p) == 0:  # nothing returns (all grazing or too far)
            return p
        ray = p / np.linalg.norm(p, axis=1, keepdims=True)
        depth = self._sensed_depth(p[:, 2], theta, rng)
        p = ray * (depth / ray[:, 2])[:, None]  # the same ray, the new depth along the axis
        if self.lateral_px > 0:
            p[:, :2] += rng.normal(size=(len(p), 2)) * (self.lateral_px * p[:, 2:3] / self.focal_px)
        p = self._flying(p, rng)
        if self.misregistration_m > 0:
            p += rng.normal(scale=self.misregistration_m, size=3)
        return p

    def apply_to_depth(
        self, depth: NDArray, focal: tuple[float, float, float, float], rng: np.random.Generator,
        surfaces: int = 5,
    ) -> NDArray[np.float64]:  # fmt: skip
        """An exact depth image (H, W) in metres (0: nothing) seen through a pinhole camera
        (``focal``: fx, fy, cx, cy in pixels) -> what this camera returns of it, (H, W) (0: no
        return): no return at grazing incidence (the surface's normal from the neighbouring
        pixels) and far away; holes, ``surfaces`` times a scan's count (a frame holds several
        objects' worth of surface); axial noise and quantisation; flying pixels where a pixel's
        neighbour lies over 0.1 m behind it (``mixed_at_edges``). The clean camera returns the
        image as it is."""
        z = np.array(depth, dtype=np.float64)
        if self.clean:
            return z
        fx, fy, cx, cy = focal
        h, w = z.shape
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        p = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], axis=-1)
        valid = z > 0
        theta = _image_incidence(p, valid)
        keep = np.zeros_like(valid)
        keep[valid] = self._returns(p[valid], theta[valid], rng)
        for _ in range(surfaces * int(rng.integers(self.holes[0], self.holes[1] + 1))):
            rows, cols = np.nonzero(keep)
            if len(rows) == 0:
                break
            k = int(rng.integers(len(rows)))
            centre = p[rows[k], cols[k]]
            keep &= np.linalg.norm(p - centre, axis=-1) > rng.uniform(*self.hole_radius_m)
        out = np.zeros_like(z)
        out[keep] = self._sensed_depth(z[keep], theta[keep], rng)
        return mixed_at_edges(out, self.flying_share, rng)

    def _sensed_depth(
        self, z: NDArray, theta: NDArray, rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """True depths (K,) at incidences ``theta`` (K,) -> the depths the camera reports: the
        axial noise, then quantised (at least 1 mm)."""
        depth = z + self.sigma_z(z, theta) * rng.normal(size=len(z))
        return np.maximum(self._quantised(np.maximum(depth, 1e-3)), 1e-3)

    def _returns(self, p: NDArray, theta: NDArray, rng: np.random.Generator) -> NDArray[np.bool_]:
        """Which points return at all: not too grazing, not too far."""
        ramp = np.clip((np.degrees(theta) - (self.max_angle_deg - 10.0)) / 10.0, 0.0, 1.0)
        near, far = self.fade_m
        if math.isfinite(near):
            ramp = np.maximum(ramp, np.clip((p[:, 2] - near) / max(far - near, 1e-6), 0.0, 1.0))
        return rng.random(len(p)) >= ramp

    def _holes(self, p: NDArray, tree: cKDTree, rng: np.random.Generator) -> NDArray[np.bool_]:
        """Points inside the scan's missing patches."""
        missing = np.zeros(len(p), dtype=bool)
        for _ in range(int(rng.integers(self.holes[0], self.holes[1] + 1))):
            centre = p[rng.integers(len(p))]
            missing[tree.query_ball_point(centre, rng.uniform(*self.hole_radius_m))] = True
        return missing

    def _quantised(self, depth: NDArray) -> NDArray[np.float64]:
        if self.disparity_step_px > 0 and self.baseline_m > 0:
            fb = self.focal_px * self.baseline_m
            disparity = np.round(fb / depth / self.disparity_step_px) * self.disparity_step_px
            depth = fb / np.maximum(disparity, self.disparity_step_px)
        if self.depth_unit_m > 0:
            depth = np.round(depth / self.depth_unit_m) * self.depth_unit_m
        return np.asarray(depth, dtype=np.float64)

    def _flying(self, p: NDArray, rng: np.random.Generator) -> NDArray[np.float64]:
        """Silhouette points pushed back along their rays (mixed returns with the background)."""
        if self.flying_share <= 0 or len(p) < 16:
            return p
        edge = np.flatnonzero(silhouette(p) & (rng.random(len(p)) < self.flying_share))
        if len(edge):
            ray = p[edge] / np.linalg.norm(p[edge], axis=1, keepdims=True)
            p = p.copy()
            p[edge] += ray * rng.uniform(*self.flying_depth_m, size=(len(edge), 1))
        return p


def _image_incidence(p: NDArray, valid: NDArray) -> NDArray[np.float64]:
    """Each pixel's angle (rad, (H, W)) between its ray and the surface's normal, the normal
    from its four neighbours' points (``p`` (H, W, 3)); 0 where a neighbour has no depth or lies
    across a depth edge (over 5% of the depth away)."""
    z = p[..., 2]
    dx, dy = np.zeros_like(p), np.zeros_like(p)
    dx[:, 1:-1], dy[1:-1] = p[:, 2:] - p[:, :-2], p[2:] - p[:-2]
    known = np.zeros_like(valid)
    known[1:-1, 1:-1] = (
        valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1]
        & (np.abs(dx[1:-1, 1:-1, 2]) < 0.1 * z[1:-1, 1:-1])
        & (np.abs(dy[1:-1, 1:-1, 2]) < 0.1 * z[1:-1, 1:-1])
    )  # fmt: skip
    normal = np.cross(dx, dy)
    norm = np.linalg.norm(normal, axis=-1) * np.linalg.norm(p, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.abs(np.einsum("hwc,hwc->hw", normal, p)) / norm
    return np.where(known, np.arccos(np.clip(np.nan_to_num(cosine, nan=1.0), 0.0, 1.0)), 0.0)


def mixed_at_edges(
    depth: NDArray, share: float, rng: np.random.Generator, step_m: float = 0.1
) -> NDArray[np.float64]:
    """A depth image (H, W) (0: no reading) -> the same with a time-of-flight camera's flying
    pixels: each pixel whose 4-neighbour reads over ``step_m`` farther is, with probability
    ``share`` per such neighbour, given a depth drawn uniformly between its own and that
    neighbour's (the pixel saw both surfaces and averaged them)."""
    out = np.array(depth, dtype=np.float64)
    if share <= 0:
        return out
    z = np.where(out > 0, out, np.nan)
    height, width = z.shape
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        behind = np.full_like(z, np.nan)  # each pixel's neighbour at (y + dy, x + dx)
        behind[max(-dy, 0) : height - max(dy, 0), max(-dx, 0) : width - max(dx, 0)] = z[
            max(dy, 0) : height + min(dy, 0), max(dx, 0) : width + min(dx, 0)
        ]
        with np.errstate(invalid="ignore"):
            edge = (behind - z > step_m) & (rng.random(z.shape) < share)
        mix = rng.random(z.shape)
        out[edge] = (z + mix * (behind - z))[edge]
    return out


def incidence(points: NDArray, tree: cKDTree | None = None, k: int = 8) -> NDArray[np.float64]:
    """Each point's angle (rad, (K,)) between its ray from the camera and the surface's normal,
    the normal from its ``k`` nearest neighbours (the smallest principal axis)."""
    tree = tree or cKDTree(points)
    k = min(k, len(points))
    _, index = tree.query(points, k=k)
    neighbours = points[index] - points[index].mean(axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(neighbours, full_matrices=False)
    normals = vt[:, -1, :]
    rays = points / np.linalg.norm(points, axis=1, keepdims=True)
    return np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", normals, rays)), 0.0, 1.0))


def silhouette(points: NDArray, k: int = 16) -> NDArray[np.bool_]:
    """Which points (K,) lie on the scan's outline as the camera sees it: in the image plane,
    the mean of a point's ``k`` neighbours lies well off the point (an edge has them on one
    side only)."""
    uv = points[:, :2] / points[:, 2:3]
    k = min(k, len(points))
    distances, index = cKDTree(uv).query(uv, k=k)
    shift = np.linalg.norm(uv[index].mean(axis=1) - uv, axis=1)
    spread = distances[:, 1:].mean(axis=1) + 1e-12
    return np.asarray(shift > 0.45 * spread)  # uniform samples of a patch: 5% inside, half the rim


SENSORS: dict[str, SensorModel] = {
    s.name: s
    for s in (
        SensorModel("clean"),
        # Structured light, 640x480 (f 580 px, baseline 7.5 cm, 1/8 px disparity steps):
        # Khoshelham and Oude Elberink 2012; Nguyen, Izadi and Lovell 2012.
        SensorModel(
            "kinect_v1", focal_px=580.0, axial=(0.0012, 0.0019, 0.4), angle_term=0.0001,
            baseline_m=0.075, lateral_px=0.8, disparity_step_px=0.125, depth_unit_m=0.001,
            max_angle_deg=75.0, fade_m=(4.0, 6.0), holes=(0, 3), flying_share=0.05,
            flying_depth_m=(0.02, 0.15), misregistration_m=0.005,
        ),
        # Time of flight, 512x424 (f 365 px): ~1.5 mm at 1 m growing slowly with depth and
        # fast with angle, strong flying pixels at edges: Fankhauser et al. 2015; Yang et al. 2015.
        SensorModel(
            "kinect_v2", focal_px=365.0, axial=(0.0015, 0.0004, 0.5), angle_term=0.0002,
            lateral_px=0.5, depth_unit_m=0.001, max_angle_deg=78.0, fade_m=(4.5, 8.0),
            holes=(0, 2), flying_share=0.15, misregistration_m=0.005,
        ),
        # Active stereo, 848x480 (f 430 px, baseline 5 cm, 0.08 px RMS subpixel, 1/32 px
        # disparity steps): Intel's D400 datasheet and depth-quality white paper; Ahn et al. 2019.
        SensorModel(
            "realsense_d435", focal_px=430.0, axial=(0.0005, 0.0, 0.0), stereo_subpixel=0.08,
            baseline_m=0.05, lateral_px=0.6, disparity_step_px=1 / 32, depth_unit_m=0.001,
            max_angle_deg=72.0, fade_m=(3.5, 7.0), holes=(0, 4), hole_radius_m=(0.03, 0.15),
            flying_share=0.1, flying_depth_m=(0.02, 0.2), misregistration_m=0.005,
        ),
    )
}  # fmt: skip
"""The named sensor models (``--sensor``)."""
