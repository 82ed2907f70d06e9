"""``SceneRequest``: what a caller may ask of a scene, declared once for ``itnet scene``,
``itnet batch scene``, ``POST /v1/scene`` (its query string), the Python clients and the page.

    request = SceneRequest(budget_ms=300, up=[0, -1, 0], recheck=False)
    find_objects(frame, camera, **request.arguments())

The depth image's intrinsics and scale describe the input, not the work: they travel beside the
request (``--intrinsics``, the query's ``fx, fy, cx, cy``), and ``depth_scale`` is a field because
every way in takes it the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field, field_validator

from itnet.request_fields import RequestModel, Xyz, parse_xyz
from itnet.scene.segment import CAMERA_UP, SegmentOptions

# A real depth camera's frame (a Kinect v2's 730 x 530, a cluttered bedroom) segments in 120-190
# ms on 2 cores and each object's naming and pose take 30-60 ms: at 500 ms every object of a
# frame of six is posed, as at about the pose path's own default each (docs/scenes.md, "Cost at
# each resolution"). A scene whose objects are posed early replies early.
DEFAULT_BUDGET_MS = 500.0
MAX_BUDGET_MS = 60_000.0


@dataclass(frozen=True)
class SceneFinishing:
    """What each posed object of a scene gets after its pose pipeline, in order; each step a
    switch, all on by default (docs/scenes.md)."""

    floor_centre: bool = True  # stood on the floor: its height from the floor (floor_centred)
    along_floor: bool = True  # its place along the floor by its pose model's scene correction
    recheck: bool = True  # a pose its verifier doubts weighed against the second category's
    # ... unless its base is out of view: it reaches within view_edge_deg of the view's bottom
    # edge, and its lowest point seen stands above this share of its top (base_low_share)
    view_edge_deg: float = 1.0
    base_low_share: float = 0.2
    # an object whose base is out of view posed by its category's network for such views
    # (``<category>_base_hidden``) where the models have one
    base_hidden_models: bool = True
    # a cluster no category fits answered as unknown (``itnet.scene.unknown``), not named ...
    unknown: bool = True
    # ... unless the recognition parts it into two objects that categories fit (``named_split``)
    named_split: bool = True


def up_direction(value: NDArray | tuple[float, float, float] | list[float] | str) -> NDArray:
    """Which way is up, three numbers or 'x,y,z' -> (3,) float64; ValueError unless they are
    three finite numbers, not all 0."""
    try:
        up = np.asarray(parse_xyz(value), dtype=np.float64)
    except ValueError:
        up = np.zeros(3)
    if not up.any():
        raise ValueError(f"up must be three finite numbers 'x,y,z', not all 0, got {value!r}")
    return up


class SceneRequest(RequestModel):
    """How long to spend on a scene and which of its steps to run."""

    model_config = ConfigDict(strict=True, extra="forbid")

    budget_ms: float = Field(
        default=DEFAULT_BUDGET_MS,
        gt=0,
        le=MAX_BUDGET_MS,
        description="time budget of the whole scene in milliseconds, counted from the request's "
        "arrival and shared among segmentation and the objects",
    )
    depth_scale: float | None = Field(
        default=None,
        gt=0,
        description="depth units per metre of a depth image (default: 1000 for 16-bit images, "
        "millimetres; 1 for float .npy, metres)",
    )
    up: Xyz = Field(
        default=None,
        description="which way is up in the camera's frame, 'x,y,z' (e.g. from an IMU's "
        "gravity); the floor is searched within 45 degrees of it (default 0,-1,0: a camera "
        "held about level)",
    )
    floor_centre: bool = Field(default=True, description="each object's height from the floor")
    along_floor: bool = Field(
        default=True,
        description="each object's place along the floor by its pose model's scene correction",
    )
    recheck: bool = Field(
        default=True,
        description="a pose its category's verifier doubts weighed against the second category's",
    )
    scene_classifier: bool = Field(
        default=True,
        description="name each object by its shape on the floor too (else the classifier and "
        "its height)",
    )
    split_touching: bool = Field(
        default=True,
        description="cut a cluster where the cut judge finds two objects standing against each "
        "other",
    )
    unknown: bool = Field(
        default=True,
        description="a cluster no category fits answered as unknown (category null), not named",
    )
    named_split: bool = Field(
        default=True,
        description="a cluster too large for its category parted where the recognition finds "
        "two objects",
    )

    room: bool | None = Field(
        default=None,
        description="the cloud is a room's: a fused reconstruction with no camera at its origin "
        "(a SLAM map, a room scan; give its up); false: a camera's view from the origin "
        "(default: decided from the cloud; a depth image is a camera's view)",
    )

    @field_validator("up")
    @classmethod
    def _a_direction(cls, up: list[float] | None) -> list[float] | None:
        return None if up is None else up_direction(up).tolist()

    def finishing(self) -> SceneFinishing:
        """The steps each posed object gets after its pose pipeline."""
        return SceneFinishing(self.floor_centre, self.along_floor, self.recheck,
                              unknown=self.unknown, named_split=self.named_split)  # fmt: skip

    def arguments(self) -> dict[str, Any]:
        """``itnet.scene.find_objects``' keywords (plain values, picklable)."""
        return {
            "budget_ms": self.budget_ms,
            "depth_scale": self.depth_scale,
            "finishing": self.finishing(),
            "scene_classifier": self.scene_classifier,
            "options": SegmentOptions(split_touching=self.split_touching),
            "expected_up": CAMERA_UP if self.up is None else tuple(self.up),
            "room": self.room,
        }
