"""``EvalOptions``: what ``itnet eval`` measures (a checkpoint or an exported model), on which
test views, and where it writes the report, the poses and the plot. ``itnet.model.eval_run``
measures them.

    report = evaluate_model(EvalOptions(onnx=Path("itnet/models/chair.onnx"), views=2))

Torch-free, so the command line imports it when it starts; the typer options of ``itnet eval``
are derived from its fields (``itnet.commands.request_options``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field


class EvalOptions(BaseModel):
    """A measurement of the anytime accuracy curve on a category's test split."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    checkpoint: Path | None = Field(None, description="torch checkpoint (.pt) to evaluate")
    onnx: Path | None = Field(None, description="or an exported .onnx step, run by onnxruntime")
    data: Path = Field(Path("../shared/data/modelnet10"), description="dataset root")
    category: str | None = Field(
        None,
        description="category of the test split (default: the model's; required for a "
        "checkpoint trained on several categories)",
    )
    frame: str = Field("modelnet", description="frame of the files: modelnet | canonical | z-up")
    views: int = Field(5, description="random views per test object")
    iterations: int = Field(20, description="evaluate iterations 0..N")
    points: int | None = Field(
        None,
        description="points each cloud is subsampled to (default: as the runtime, the model "
        "card's count; for a checkpoint, its training count)",
    )
    seed: int = Field(2024, description="seed of the test views")
    scanner: str = Field(
        "occluded",
        description="test views: 'occluded' (z-buffer with the 3x3 occlusion test, the "
        "product's benchmark), 'paper' (the paper's nearest point per pixel) or 'surface' (each "
        "point a disc, as a camera sees a mesh), or RULE+SENSOR (occluded+kinect_v2: by that "
        "depth camera, at the category's real sizes); see model/scanner.py",
    )
    out: Path = Field(Path("runs/eval"), description="folder for report.json and anytime.png")
    dump_scans: Path | None = Field(
        None,
        description="also write the test scans as .npy files plus labels.json (for `itnet pose`)",
    )
    check_orientation: bool = Field(
        True, description="turn back or drop test shapes turned about up, as training does"
    )
    cache: Path = Field(Path("cache"), description="cache of canonical shapes and fixed scans")
    up: float | None = Field(
        None,
        ge=0.0,
        description="give each run its scan's up direction, tilted this many degrees from the "
        "truth (a gravity sensor's error), and hold it upright as the service does. Default: "
        "none, or 2 for a model whose card requires up",
    )
