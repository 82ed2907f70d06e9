"""The view's edges measured on a scene's points, and which of them a part reaches."""

from __future__ import annotations

import numpy as np

from itnet.model.scenes import Scene
from itnet.scene import SceneFinishing
from itnet.scene.inputs import from_depth
from itnet.scene.pipeline import base_out_of_view
from itnet.scene.segment import segment
from itnet.scene.view_edges import ViewEdges


def rays(width: int = 64, height: int = 48, depth: float = 3.0) -> np.ndarray:
    """A pinhole camera's pixels (H * W, 3) at ``depth``: fx = fy = 50, centred."""
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    z = np.full(u.size, depth)
    return np.stack([(u.ravel() - width / 2) * z / 50, (v.ravel() - height / 2) * z / 50, z], 1)


def test_the_edges_are_the_border_pixels_rays_whatever_their_depth() -> None:
    points = rays()
    points[::7] *= 2.5  # another depth along the same rays
    edges = ViewEdges.of_points(points)
    assert edges is not None
    assert np.isclose(edges.top, np.arctan(-24 / 50)) and np.isclose(
        edges.bottom, np.arctan(23 / 50)
    )
    assert np.isclose(edges.left, np.arctan(-32 / 50)) and np.isclose(
        edges.right, np.arctan(31 / 50)
    )
    assert ViewEdges.of_points(-points) is None  # nothing ahead of the camera


def test_a_part_reaches_the_edges_it_touches() -> None:
    points = rays()
    edges = ViewEdges.of_points(points)
    assert edges is not None
    grid = points.reshape(48, 64, 3)
    assert edges.reached(grid[40:, 10:20].reshape(-1, 3)) == ("bottom",)
    assert edges.reached(grid[:10, 50:].reshape(-1, 3)) == ("top", "right")
    assert edges.reached(grid[10:30, 10:30].reshape(-1, 3)) == ()
    # within 1 degree: 0.8 pixel here; two pixels short of the bottom edge is not reaching it
    assert edges.reached(grid[30:46, 10:20].reshape(-1, 3)) == ()
    assert edges.reached(grid[30:46, 10:20].reshape(-1, 3), within_deg=3.0) == ("bottom",)
    assert edges.reached(np.empty((0, 3))) == ()


def test_a_chair_seen_from_its_seat_up_has_its_base_out_of_view(
    level_chair_scene: Scene, chair_scene: Scene
) -> None:
    """A level camera 1.7 m up sees a chair 2.2 m away from its seat up; a chair 3 m before the
    usual camera is seen down to the floor."""
    for scene, hidden in ((level_chair_scene, True), (chair_scene, False)):
        given = from_depth(scene.depth, scene.intrinsics)
        found = segment(given.points)
        (rows,) = found.objects
        edges = found.edges
        assert edges == ViewEdges.of_points(given.points)  # the segmentation measured the view
        chair = given.points[rows]
        assert base_out_of_view(edges, chair, found.floor, SceneFinishing()) is hidden
        assert not base_out_of_view(edges, chair, None, SceneFinishing())
        # reaching the bottom edge with its lowest fifth in view is whole enough
        low = SceneFinishing(base_low_share=1.0)
        assert not base_out_of_view(edges, chair, found.floor, low)
