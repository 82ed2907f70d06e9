"""``CentreFitOptions``: how ``itnet centre-fit`` fits and measures a pose model's object-centre
correction: the shapes and views it poses, the fit, the runs (fused, held upright), and where
the correction and its measurement go. ``itnet.model.centre_fit_run`` fits with them.

    fit_model_centre(Path("bed.onnx"), CentreFitOptions(ensemble=8, write=True))

Torch-free, so the command line imports it when it starts; the typer options of
``itnet centre-fit`` are derived from its fields (``itnet.commands.request_options``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator


class CentreFitOptions(BaseModel):
    """A centre correction's fit on the category's training shapes and its measurement on the
    validation views."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    data: Path = Field(Path("../shared/data/modelnet10"), description="ModelNet-style root")
    views: int = Field(3, ge=1, description="views per training shape (each kind of view)")
    kinds: str = Field(
        "occluded,paper",
        pattern=r"^[a-z0-9_+]+(,[a-z0-9_+]+)*$",
        description="the kinds of view fitted on and measured on, comma-separated view rules "
        "(a rule with a camera, such as occluded+kinect_v2, scans real-sized pieces through its "
        "sensor model)",
    )
    val_views: int = Field(8, ge=1, description="views per validation shape, to measure it")
    ridge: float = Field(10.0, ge=0.0, description="ridge weight (standardised features)")
    seed: int = Field(4242, description="seed of the training shapes' views")
    ensemble: int = Field(
        1,
        ge=1,
        le=16,
        description="pose the scans with this many runs fused (the card's default for a model "
        "served that way), to fit and to measure",
    )
    max_rotation: float = Field(
        20.0,
        description="fit on the training scans posed within this many degrees (a wrong basin's "
        "centre teaches nothing)",
    )
    write: bool = Field(False, description="write the correction and its measurement into the card")
    out: Path | None = Field(None, description="with --write: write here instead of changing MODEL")
    report: Path | None = Field(None, description="write the measurement (JSON) here")
    cache: Path = Field(Path("cache"), description="cache of shapes and scans")
    up: float | None = Field(
        None,
        description="fit and measure the correction for requests that give the up direction: "
        "every scan's runs held upright by its up, tilted this many degrees from the truth (a "
        "gravity sensor's error); with --write it becomes the card's centre_correction_up, and "
        "its viewpoint variant centre_correction_up_viewpoint (requests that give both)",
    )
    keep_viewpoint: bool = Field(
        True,
        description="with --write, write the viewpoint variant too; --no-keep-viewpoint "
        "measures it but leaves the card's as it is (its measurement is marked not kept)",
    )

    @field_validator("out")
    @classmethod
    def _an_onnx_file(cls, out: Path | None) -> Path | None:
        if out is not None and out.suffix != ".onnx":
            raise ValueError(f"the model is written as ONNX: give a .onnx path, not {out}")
        return out
