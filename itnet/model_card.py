"""What a shipped model file says about itself (stored as JSON in the ONNX metadata, key 'itnet').

Shared by the exporter (writes it) and the runtime (reads it), so both agree on the fields.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

METADATA_KEY = "itnet"
NORMALIZATION = "centroid, RMS radius (itnet.preprocess)"


class ModelCard(BaseModel):
    """Metadata of one exported IT-Net step."""

    name: str = Field(description="model name used in requests, e.g. 'chair'")
    category: str
    version: str = "1"
    precision: str = Field(
        "float32", description="'float32', or 'int8' (per-point layers dynamically quantised)"
    )
    points: int = Field(
        1024, description="points the runtime subsamples a larger cloud to (a smaller one: whole)"
    )
    trained_points: int = 256
    trained_iterations: int = 5
    recommended_iterations: int = 10
    normalization: str = NORMALIZATION
    canonical_frame: str = "+y up, front toward -z, origin at the bounding-box centre"
    symmetry: Literal["none", "yaw180", "yaw90", "yaw"] = Field(
        "none",
        description="rotations about +y (up) that leave the category's shapes alike: 'none', "
        "'yaw180' (C2), 'yaw90' (C4) or 'yaw' (any turn: round objects); a pose is correct when "
        "any equivalent pose is",
    )
    inputs: dict[str, str] = {
        "points": "float32 [B, N, 3], normalised cloud",
        "pose": "float32 [B, 4, 4], pose so far (normalised frame)",
    }
    outputs: dict[str, str] = {
        "pose_next": "float32 [B, 4, 4], update @ pose",
        "delta": "float32 [B, 4, 4], this step's update",
    }
    accuracy: dict[str, float] = Field(
        default_factory=dict,
        description="measured accuracy at (10 deg, 0.1 radius) by iteration count, e.g. {'10': 0.7}",
    )
    evaluation: str = ""
    training: dict[str, object] = Field(default_factory=dict)
