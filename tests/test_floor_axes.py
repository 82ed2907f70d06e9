"""``itnet.planes.floor_axes``: two unit directions along the floor, normal to up and to each
other, and the cross product it uses gives numpy's numbers."""

import numpy as np

from itnet.planes import _cross, floor_axes


def test_the_cross_product_is_numpys() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        a, b = rng.normal(size=3), rng.normal(size=3)
        assert np.array_equal(_cross(a, b), np.cross(a, b))
        assert np.array_equal(_cross(a, (1.0, 0.0, 0.0)), np.cross(a, [1.0, 0.0, 0.0]))


def test_floor_axes_are_orthonormal_and_level() -> None:
    rng = np.random.default_rng(1)
    for up in [np.array([0.0, -1.0, 0.0]), np.array([1.0, 0.0, 0.0]), *rng.normal(size=(20, 3))]:
        up = up / np.linalg.norm(up)
        across, along = floor_axes(up)
        frame = np.stack([across, along, up])
        assert np.allclose(frame @ frame.T, np.eye(3), atol=1e-12)
