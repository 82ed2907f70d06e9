"""Fixtures of the scene tests: scenes of boxes and a box-built chair (scene_helpers.py)."""

from __future__ import annotations

import pytest
from scene_helpers import boxes_shape, chair_shape, make_test_scene

from itnet.model.scenes import Scene


@pytest.fixture(scope="session")
def two_boxes() -> Scene:
    box = boxes_shape([((0, 0, 0), (0.5, 0.6, 0.4))])
    return make_test_scene([(box, 0.4, -0.7, 3.0, 20.0), (box, 0.4, 0.7, 3.2, -30.0)])


@pytest.fixture(scope="session")
def chair_scene() -> Scene:
    return make_test_scene([(chair_shape(), 0.5, 0.2, 3.0, 160.0)])


@pytest.fixture(scope="session")
def empty_scene() -> Scene:
    return make_test_scene([])


@pytest.fixture(scope="session")
def level_chair_scene() -> Scene:
    """A level camera 1.7 m up, a chair 2.2 m away: its base is below the view."""
    return make_test_scene([(chair_shape(), 0.5, 0.0, 2.2, 200.0)], camera_height=1.7,
                           pitch_deg=0.0)  # fmt: skip
