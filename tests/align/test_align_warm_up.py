"""The alignment's warm-up (``itnet.alignment.warm_up``): what a first alignment loads, loaded
on a made-up pair before a server's first alignment, with no network step."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from itnet.alignment.refine import refine_wanted
from itnet.alignment.warm_up import TURN_DEG, made_up_pair, warm_up
from itnet.geometry import apply_rigid, rotation_error_deg


def test_the_made_up_pair_is_a_box_and_its_turned_copy() -> None:
    a, b, b_from_a = made_up_pair()
    assert a.shape == b.shape == (512, 3)
    assert np.allclose(apply_rigid(b_from_a, a), b)
    assert abs(rotation_error_deg(b_from_a[:3, :3], np.eye(3)) - TURN_DEG) < 1e-9
    assert np.ptp(a, axis=0) == pytest.approx([0.6, 0.8, 0.4], abs=0.01)


def test_warming_up_loads_the_alignment_and_refines_where_open3d_is() -> None:
    ran_icp = warm_up()
    assert "itnet.alignment.pipeline" in sys.modules
    assert ran_icp == refine_wanted(None)
