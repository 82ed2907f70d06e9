"""``BuildConfig``: how ``itnet build CATEGORY`` rebuilds a category's shipped model (torch-free,
so the command's options are derived from it without importing torch)."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field


class BuildConfig(BaseModel):
    """A category's model from its data to the shipped files: the pose network fine-tuned from
    earlier weights, measured, exported, its verifier, its centre corrections, its card's
    measurements as served, and the file compacted."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    category: str = Field(default="chair", description="a category of the registry (ModelNet10)")
    data: Path = Field(default=Path("../shared/data/modelnet10"), description="ModelNet10 root")
    out: Path | None = Field(
        default=None, description="the build's folder (default: runs/build/CATEGORY)"
    )
    init_from: Path | None = Field(
        default=None,
        description="weights to fine-tune from (default: lab/weights/CATEGORY.pt where it "
        "exists, else lab/weights/chair.pt)",
    )
    steps: int = Field(default=3000, ge=1, description="fine-tuning steps")
    batch: int = Field(default=32, ge=2, description="scans a training step")
    lr: float = Field(default=3e-4, gt=0, description="initial learning rate")
    decay_every: int = Field(default=750, ge=1, description="learning rate x0.7 every N steps")
    eval_every: int = Field(default=500, ge=1, description="validate every N steps")
    threads: int = Field(default=0, ge=0, description="torch threads (0: torch's default)")
    compile: bool = Field(
        default=True,
        description="compile the training step with torch.compile (~1.7x on a CPU, after a "
        "first compile of about a minute)",
    )
    views: int = Field(default=5, ge=1, description="test views per shape, for the measurements")
    runs: int = Field(default=8, ge=1, le=16, description="runs fused by default (the card's)")
    budget_ms: float = Field(default=50.0, gt=0, description="each measured pose's budget")
    verifier_steps: int = Field(default=3000, ge=1, description="the verifier's training steps")
    verifier_views: int = Field(
        default=8, ge=1, description="scans of each training shape a view rule, for the verifier"
    )
    centre_views: int = Field(default=3, ge=1, description="views a shape for the centre fit")
    up_error_deg: float = Field(
        default=2.0, ge=0, le=45, description="how far off the up is given, where it is needed"
    )
    cache: Path = Field(default=Path("cache"), description="cache of shapes and scans")

    def folder(self) -> Path:
        """Where the build writes: ``out``, or runs/build/CATEGORY."""
        return self.out or Path("runs/build") / self.category

    def weights(self) -> Path:
        """The weights the fine-tune starts from."""
        if self.init_from is not None:
            return self.init_from
        own = Path("lab/weights") / f"{self.category}.pt"
        return own if own.exists() else Path("lab/weights/chair.pt")
