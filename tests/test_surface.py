"""Surface views: each point a disc, z-buffered so that near surfaces hide far ones."""

import numpy as np
import pytest

from itnet.geometry import apply_rigid, invert_rigid
from itnet.model.scanner import (
    PAPER_VIEWS,
    SURFACE_VIEWS,
    ScanConfig,
    random_camera_pose,
    scan_config,
    scan_of,
    surfel_scan,
    zbuffer_scan,
)
from itnet.model.shapes import Shape
from itnet.model.surface import surface_discs


def _sphere(rng, n=1024):
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _facing(points, camera_from_canonical):
    """Cosine between each unit-sphere point's normal and its direction to the camera (M,)."""
    centre = invert_rigid(camera_from_canonical)[:3, 3]
    to_camera = centre - points
    return np.einsum("ij,ij->i", points, to_camera / np.linalg.norm(to_camera, axis=1)[:, None])


def test_discs_of_a_plane_are_flat_and_as_wide_as_the_grid():
    u, v = np.meshgrid(np.arange(20) * 0.05, np.arange(20) * 0.05)
    plane = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], 1)
    normals, spacing = surface_discs(plane @ _tilt(0.4).T)
    assert np.allclose(np.abs(normals @ _tilt(0.4)[:, 2]), 1.0, atol=1e-9)
    # Inside the grid: 4 neighbours at 0.05 and 4 at 0.05·√2; on its edges, farther ones.
    assert np.isclose(np.median(spacing), 0.05 * (1 + np.sqrt(2)) / 2)
    assert np.all((spacing > np.median(spacing) - 1e-9) & (spacing < 0.1))
    with pytest.raises(ValueError, match="at least 3 points"):
        surface_discs(plane[:2])


def _tilt(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


@pytest.mark.parametrize("pixel", [0.035, 0.07])
def test_a_sparse_sphere_hides_its_far_side_as_a_surface_would(rng, pixel):
    """1,024 points on a unit sphere (the spacing of a ModelNet shape): the point z-buffer lets
    much of the far half through the holes; the discs hide it and keep what faces the camera."""
    sphere = _sphere(rng)
    discs = surface_discs(sphere)
    back_seen, front_seen, paper_back_seen = [], [], []
    for _ in range(10):
        cam = random_camera_pose(rng, ScanConfig())
        facing = _facing(sphere, cam)
        seen = _mask(sphere, cam, surfel_scan(sphere, discs, cam, pixel, 1.0, 0.03))
        paper = _mask(sphere, cam, zbuffer_scan(sphere, cam, pixel, 0.0, np.inf))
        back_seen.append(seen[facing < -0.2].mean())
        front_seen.append(seen[facing > 0.4].mean())
        paper_back_seen.append(paper[facing < -0.2].mean())
    assert np.mean(back_seen) < 0.03 and np.mean(front_seen) > 0.95
    assert np.mean(paper_back_seen) > 0.3


def _mask(points, cam, seen_camera_points):
    """Which of ``points`` (M, 3) a scan in the camera frame kept (M,)."""
    back = apply_rigid(invert_rigid(cam), seen_camera_points)
    d = np.linalg.norm(points[:, None] - back[None], axis=-1)
    return d.min(1) < 1e-9


def test_a_steep_plane_does_not_hide_itself(rng):
    """A plane turned 65 degrees away from the camera is seen whole: each disc lies in it."""
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, 25), np.linspace(-0.5, 0.5, 25))
    plane = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], 1) @ _tilt(np.radians(65)).T
    cam = np.eye(4)
    cam[2, 3] = 3.0  # looking along +z at the plane's centre
    seen = surfel_scan(plane, surface_discs(plane), cam, 0.05, 1.0, 0.03)
    assert len(seen) == len(plane)


def test_surface_scans_of_a_shape_reuse_its_discs(rng, monkeypatch):
    shape = Shape("ball", _sphere(rng, 600))
    config = scan_config(SURFACE_VIEWS)
    cloud, pose = scan_of(shape, rng, config)
    first = shape.discs()
    cloud2, _ = scan_of(shape, rng, config)
    assert shape.discs() is first  # computed once, kept on the shape
    back = apply_rigid(pose, cloud)  # sensor noise on: close to the sphere, not on it
    assert np.abs(np.linalg.norm(back, axis=1) - 1).mean() < 0.1
    assert 0.15 * 600 < len(cloud) < 0.6 * 600 and 0.15 * 600 < len(cloud2) < 0.6 * 600
    # A point-z-buffer rule leaves the shape without discs.
    scan_of(Shape("other", _sphere(rng, 600)), rng, scan_config(PAPER_VIEWS))


def test_discs_come_out_the_same_a_few_rows_at_a_time(rng):
    points = rng.normal(size=(700, 3))
    whole, blocked = surface_discs(points), surface_discs(points, cells=5000)  # 7 rows a block
    assert np.allclose(np.abs(np.einsum("ij,ij->i", whole[0], blocked[0])), 1.0)
    assert np.allclose(whole[1], blocked[1])
