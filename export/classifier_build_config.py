"""``ClassifierExportConfig``: how a trained classifier run becomes a served graph: where the
ONNX file goes, the points it is served at, int8 or float32, fused heads and their cascade,
the classifier an upright graph is served beside, and what else to write (the report, the
confusion plot, the shipped weights). ``itnet.export.classifier_build`` exports with it.

    export_classifier_run(Path("runs/cls/itnet-2"), ClassifierExportConfig(int8=True))

Torch-free, so the command line imports it when it starts; the typer options of
``itnet classify-export`` are derived from its fields (``itnet.commands.request_options``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

CLASSIFIER = Path("itnet/models/classifier.onnx")
"""The shipped classifier for any orientation."""


class ClassifierExportConfig(BaseModel):
    """Everything ``itnet classify-export`` takes beside the run."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    out: Path = Field(
        CLASSIFIER,
        description="output .onnx file (an upright run's: itnet/models/classifier_upright.onnx)",
    )
    points: int | None = Field(None, description="points per cloud at serving (default: trained)")
    canonical_points: int | None = Field(
        None,
        ge=1,
        description="the canonicaliser finds the pose from this many of the points (random "
        "ones), the classifier sees them all: faster (docs/classification.md). Default: as "
        "trained (all)",
    )
    int8: bool = Field(
        False, description="quantise the per-point layers to int8 (faster on 2 cores)"
    )
    target: float = Field(
        0.95,
        description="unsure threshold: the lowest at which this share of validation views is right",
    )
    report: Path | None = Field(
        None,
        description="also write the card, the graph's test metrics (per class, confusion "
        "matrix) and the threshold's effect on the test views (JSON)",
    )
    confusion: Path | None = Field(
        None,
        description="also plot the graph's test confusion matrix here (PNG; docs/confusion.png)",
    )
    weights_out: Path | None = Field(
        None,
        description="also copy the run's best torch weights here, without optimiser state "
        "(what a later fine-tune starts from: classify-train --init-from)",
    )
    fuse_with: list[Path] = Field(
        [],
        description="also these classifier checkpoints' heads, behind the same canonicaliser "
        "(they must hold the run's transformer weights: heads trained with "
        "--freeze-transformer); the graph answers with their mean log-probability "
        "(docs/classification.md)",
    )
    cascade: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="with --fuse-with: the other heads run only for looks whose first head (the "
        "run's; give the cheaper one first) has a top probability below this, the rest get the "
        "first head's answer: about the fused accuracy at a fraction of its time "
        "(docs/classification.md). Default: every head always",
    )
    beside: Path = Field(
        CLASSIFIER,
        description="an upright run's graph is served fused with this classifier for any "
        "orientation: its card's accuracy and threshold are measured so",
    )

    @field_validator("cascade")
    @classmethod
    def _heads_to_cascade_to(cls, cascade: float | None, info: ValidationInfo) -> float | None:
        if cascade is not None and not info.data.get("fuse_with"):
            raise PydanticCustomError("refused", "needs heads to cascade to (--fuse-with)")
        if cascade is not None and info.data.get("int8"):
            raise PydanticCustomError("refused", "is for float32 graphs (not with --int8)")
        return cascade
