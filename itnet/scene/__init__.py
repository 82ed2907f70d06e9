"""Scenes: a depth image or a room's cloud in, every object's category and pose out.

    from itnet.scene import Intrinsics, find_objects
    result = find_objects(depth, Intrinsics(fx, fy, cx, cy), budget_ms=100)

See docs/scenes.md.
"""

from itnet.scene.camera import (
    Intrinsics,
    SceneInputError,
    SceneTooLargeError,
    intrinsics_from_json,
    parse_intrinsics,
)
from itnet.scene.inputs import (
    SceneInput,
    SceneLimits,
    from_array,
    from_cloud,
    from_depth,
    from_file,
    from_png,
)
from itnet.scene.pipeline import find_objects
from itnet.scene.posing import scene_catalog
from itnet.scene.request import DEFAULT_BUDGET_MS, SceneFinishing, SceneRequest
from itnet.scene.result import Box, SceneObject, SceneResult
from itnet.scene.scene_classifier import SceneClassifier, load_scene_classifier
from itnet.scene.segment import SegmentOptions

__all__ = [
    "DEFAULT_BUDGET_MS",
    "Box",
    "Intrinsics",
    "SceneClassifier",
    "SceneFinishing",
    "SceneInput",
    "SceneInputError",
    "SceneLimits",
    "SceneObject",
    "SceneRequest",
    "SceneResult",
    "SceneTooLargeError",
    "SegmentOptions",
    "find_objects",
    "from_array",
    "from_cloud",
    "from_depth",
    "from_file",
    "from_png",
    "intrinsics_from_json",
    "load_scene_classifier",
    "parse_intrinsics",
    "scene_catalog",
]
