"""``ExportOptions``: how a trained checkpoint becomes a served model: where the ONNX file goes,
the name and category it answers for, and what its card says (points, iterations, fused runs,
mirror planes, measurements). ``itnet.export.checkpoint_export`` exports with them.

    export_checkpoint(Path("runs/bed/best.pt"), ExportOptions(name="bed", int8=True))

Torch-free, so the command line imports it when it starts; the typer options of
``itnet export`` are derived from its fields (``itnet.commands.request_options``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field


class ExportOptions(BaseModel):
    """Everything ``itnet export`` takes beside the checkpoint."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    out: Path | None = Field(
        None, description="output .onnx file (default: itnet/models/<name>.onnx)"
    )
    name: str | None = Field(
        None, description="model name used in requests (default: the category)"
    )
    category: str | None = Field(
        None,
        description="category the model answers for (default: the one it was trained on; "
        "required for a network trained on several: export it once per category)",
    )
    points: int | None = Field(
        None,
        description="points the runtime subsamples a larger cloud to (default: the count the "
        "model was trained on: the density it knows, and the cheapest step)",
    )
    recommended_iterations: int = Field(10, description="default iteration cap of the runtime")
    recommended_ensemble: int = Field(
        1,
        ge=1,
        le=16,
        description="runs fused per estimate when a request does not say (needs "
        "--ensemble-report above 1)",
    )
    mirror_planes: str | None = Field(
        None,
        description="canonical planes the category is mirror-symmetric about, comma-separated: "
        "'x' (x = 0, left-right), 'z' (z = 0, front-back), or 'none'; the runtime finishes "
        "poses by them (itnet.mirror). Default: measured for ModelNet10's classes (`itnet fit "
        "categories`), none for your own category",
    )
    report: Path | None = Field(
        None, description="an `itnet eval` report.json to record as the card's accuracy"
    )
    ensemble_report: Path | None = Field(
        None, description="JSON of `python -m benchmarks.bench_ensemble` measuring that ensemble"
    )
    version: str = Field("1", description="the model's version on its card")
    int8: bool = Field(
        False, description="quantise the per-point layers to int8 (1.3x faster on 2 cores)"
    )
