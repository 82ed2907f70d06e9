"""The alignment's warm-up (``itnet.alignment.warm_up``): its made-up pair, aligned once before
a server's first alignment."""

from __future__ import annotations

import numpy as np


def test_the_alignment_warm_up_aligns_its_made_up_pair() -> None:
    """The made-up pair is a box and the same box turned 30 degrees and moved; warming up aligns
    it with the default model (the modules, open3d where installed, and the calibration
    loaded: the first alignment a caller sends does not pay for them)."""
    import sys

    from itnet.alignment.refine import refine_wanted
    from itnet.alignment.warm_up import TURN_DEG, made_up_pair, warm_up
    from itnet.geometry import rotation_error_deg
    from itnet.pose.catalog import Catalog

    a, b = made_up_pair()
    assert a.shape == b.shape == (512, 3)
    assert np.allclose(np.linalg.norm(b - b.mean(0), axis=1), np.linalg.norm(a - a.mean(0), axis=1))
    centred = np.linalg.lstsq(a - a.mean(0), b - b.mean(0), rcond=None)[0].T
    assert abs(rotation_error_deg(centred, np.eye(3)) - TURN_DEG) < 1e-6
    warm_up(Catalog.load())
    assert "itnet.alignment.pipeline" in sys.modules
    assert ("open3d" in sys.modules) == refine_wanted(None)
