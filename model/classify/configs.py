"""What the classifier's build steps are asked for, one typed config each, with the command
line's defaults: ``ClassifyTrainConfig`` (one run, ``itnet classify-train``),
``ClassifyExperimentConfig`` (the transformer table, ``itnet classify-experiment``) and
``SizePriorFitConfig`` (the card's size prior, ``itnet classify-size-prior``).

    report = train_classifier(ClassifyTrainConfig(out=Path("runs/cls"), head="local"))

Torch-free, so the command line imports it when it starts; the commands' typer options are
derived from the fields (``itnet.commands.request_options``). View rules and elevations are
text as the command line gives them ('occluded,paper', '-10,55'), checked here: a bad value is
refused with the field named.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator
from pydantic_core import PydanticCustomError

DATA = Path("../shared/data/modelnet10")
"""The ModelNet10 root of the repository's layout."""


def view_rule_names(text: str) -> tuple[str, ...]:
    """'RULE,RULE+SENSOR,...' -> the view rule names (``model.classify.data.view_configs``),
    at least one. Raises ValueError for an unknown rule or sensor, or none."""
    from itnet.model.classify.data import view_configs

    rules = tuple(rule.strip() for rule in text.split(",") if rule.strip())
    view_configs(rules or ("",))
    return rules


def degrees_range(text: str) -> tuple[float, float]:
    """'MIN,MAX' degrees, -90 < MIN <= MAX < 90 -> (MIN, MAX). Raises ValueError otherwise."""
    try:
        low, high = (float(part) for part in text.split(","))
    except ValueError:
        raise ValueError("two numbers, MIN,MAX") from None
    if not -90 < low <= high < 90:
        raise ValueError("degrees with -90 < MIN <= MAX < 90")
    return low, high


def checked(parse: Callable[[str], object], text: str) -> str:
    """``text`` where ``parse`` takes it; otherwise ``parse``'s ValueError as a field
    validator's refusal, its message as it is (no 'Value error, ' before it)."""
    try:
        parse(text)
    except ValueError as error:
        raise PydanticCustomError("refused", "{message}", {"message": str(error)}) from None
    return text


class ClassifyTrainConfig(BaseModel):
    """One classifier run as ``itnet classify-train`` asks for it (the defaults: the shipped
    classifier's recipe, a table row trained longer); ``train_run.classify_config`` makes it
    the run's ``ClassifyConfig``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    variant: str = Field("itnet-2", description="row of the table: none, tnet-1, ..., itnet-2")
    data: Path = Field(DATA, description="ModelNet-style root")
    out: Path = Field(Path("runs/cls-ship/itnet-2"), description="run folder")
    steps: int = Field(3200, description="optimiser steps")
    lr: float = Field(5e-4, description="initial Adam learning rate")
    decay_every: int = Field(800, description="multiply the learning rate by 0.7 every N steps")
    bn_momentum: float = Field(0.1, description="BatchNorm momentum at step 0 (floor 0.01)")
    init_from: Path | None = Field(None, description="start from this checkpoint's weights")
    balanced: bool = Field(
        False,
        description="classes weigh alike: drawn uniformly into batches, best.pt chosen on the "
        "validation's mean class accuracy",
    )
    up_weight: float = Field(
        0.0,
        ge=0.0,
        description="also teach IT-Net to stand views up (weight of the up-axis term; 0: the "
        "paper's class loss alone)",
    )
    stretch: float = Field(
        1.0,
        ge=1.0,
        description="stretch each training shape along its axes by factors drawn log-uniformly "
        "in [1/S, S] before it is scanned (1: off): more shapes than the dataset has",
    )
    upright: float | None = Field(
        None,
        ge=0.0,
        description="upright views: each levelled by its up direction with up to DEG degrees of "
        "error (validation and test: 2); the classifier for requests that give up. Default: "
        "full SO(3)",
    )
    views: str = Field(
        "occluded,paper",
        description="view rules of training, validation and test, comma-separated: occluded, "
        "paper, surface, base_hidden, each as rendered or by a depth camera (RULE+SENSOR, e.g. "
        "occluded+kinect_v2: at real sizes), cut out of a room (RULE+SENSOR+crop) or out of a "
        "furnished one (RULE+SENSOR+clutter; docs/training.md)",
    )
    elevation: str | None = Field(
        None,
        description="MIN,MAX: cameras only this many degrees over the shape's horizon (e.g. "
        "-10,55: held above the floor, as scenes see furniture). Default: any direction",
    )
    canonical_points: int | None = Field(
        None,
        ge=1,
        description="the transformer finds its pose from this many of the points (random "
        "ones), as classify-export --canonical-points serves it. Default: all",
    )
    label_smoothing: float = Field(
        0.0,
        ge=0.0,
        le=0.5,
        description="smooth the cross-entropy's targets by E (1 - E on the class; 0: off)",
    )
    hold_test: bool = Field(
        False,
        description="end without measuring the test split (an experiment whose choice is still "
        "open); classify-export measures the exported graph on it",
    )
    ema: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="also keep an exponential moving average of the weights (decay per step, "
        "e.g. 0.999), validated beside the raw weights; best.pt keeps whichever scores higher",
    )
    head: str = Field(
        "pointnet",
        description="the classifier after the transformer: pointnet (the paper's) or local "
        "(each layer mixes in every point's nearest neighbours; docs/classification.md)",
    )
    neighbours: int | None = Field(
        None, ge=1, description="neighbours of each point (--head local; default 16)"
    )
    transformer_from: Path | None = Field(
        None,
        description="start the transformer (only) from this classifier checkpoint's, e.g. a new "
        "head behind lab/weights/classifier.pt's canonicaliser",
    )
    freeze_transformer: bool = Field(
        False,
        description="do not train the transformer (its weights and BatchNorm statistics stay)",
    )
    init_seed: int | None = Field(
        None,
        description="seed of the initialisation and the batches (default: the split's, 0): "
        "another network on the same training and validation split",
    )
    eval_every: int = Field(200, description="validate and checkpoint every N steps")
    threads: int = Field(1, description="torch threads")
    compile: bool = Field(
        True,
        description="compile the training step with torch.compile (~1.7x on a CPU; eager if it "
        "cannot compile)",
    )
    cache: Path = Field(Path("cache"), description="cache of shapes and fixed views")
    batch: int = Field(32, ge=1, description="views per step")
    device: str = Field("cpu", description="torch device: cpu | cuda")
    data_workers: int = Field(
        0, ge=0, description="processes making the views ahead of each step (for a GPU: ~2)"
    )

    @field_validator("views")
    @classmethod
    def _known_views(cls, views: str) -> str:
        return checked(view_rule_names, views)

    @field_validator("elevation")
    @classmethod
    def _an_elevation(cls, elevation: str | None) -> str | None:
        return None if elevation is None else checked(degrees_range, elevation)

    def view_rules(self) -> tuple[str, ...]:
        """The view rules of ``views``, in order."""
        return view_rule_names(self.views)

    def elevation_range(self) -> tuple[float, float] | None:
        """(MIN, MAX) degrees of ``elevation``; None: any direction."""
        return None if self.elevation is None else degrees_range(self.elevation)


class ClassifyExperimentConfig(BaseModel):
    """The transformer table as ``itnet classify-experiment`` asks for it: every row trained
    with the same budget into OUT/<variant>, then the report written into ``docs``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    data: Path = Field(DATA, description="ModelNet-style root (DATA/CLASS/{train,test})")
    out: Path = Field(Path("runs/cls"), description="folder of the rows' runs")
    steps: int = Field(1200, description="optimiser steps of every row (the same budget each)")
    batch: int = Field(32, description="views per step")
    points: int = Field(256, description="points per view")
    decay_every: int = Field(240, description="multiply the learning rate by 0.7 every N steps")
    eval_every: int = Field(200, description="validate and checkpoint every N steps")
    test_views: int = Field(4, description="fixed views per test shape (half occluded)")
    threads: int = Field(1, description="torch threads")
    compile: bool = Field(
        True,
        description="compile the training step with torch.compile (~1.7x on a CPU; eager if it "
        "cannot compile)",
    )
    seed: int = Field(0, description="seed of the validation split, the fixed views and the runs")
    cache: Path = Field(Path("cache"), description="cache of shapes and fixed views")
    docs: Path | None = Field(
        Path("docs"),
        description="write classification.md/.json and confusion_table.png here (none: skip)",
    )
    report_only: bool = Field(False, description="only rewrite the report from finished rows")


class SizePriorFitConfig(BaseModel):
    """The classifier's size prior as ``itnet classify-size-prior`` fits it: on views of the
    training shapes (their files' units read as inches, or real sizes), measured on views of
    the validation or test shapes, written into the card with ``write``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    classifier: Path = Field(
        Path("itnet/models/classifier.onnx"),
        description="the exported classifier whose card to update",
    )
    data: Path = Field(DATA, description="ModelNet-style root")
    views: int = Field(2, description="random views per training shape to fit the sizes on")
    df: float = Field(3.0, description="Student-t degrees of freedom of each class's log size")
    weight: float = Field(0.5, description="weight of the size's log-likelihood")
    split: Literal["val", "test"] = Field(
        "val",
        description="where to measure it: 'val' (choose here) or 'test' (once, after choosing)",
    )
    write: bool = Field(False, description="write the prior and its measurement into the card")
    cache: Path = Field(Path("cache"), description="cache of shapes")
    sizes: Literal["inches", "real"] = Field(
        "inches",
        description="the shapes' sizes: 'inches' (ModelNet's units read as inches) or 'real' "
        "(each view at a real piece's size, drawn from the category's range: docs/training.md)",
    )
    rules: str = Field(
        "occluded,paper",
        description="view rules of the fitting and measuring views, in turn (RULE or "
        "RULE+SENSOR, as classify-train --views)",
    )

    @field_validator("rules")
    @classmethod
    def _known_rules(cls, rules: str) -> str:
        return checked(view_rule_names, rules)

    def view_rules(self) -> tuple[str, ...]:
        """The view rules of ``rules``, in order."""
        return view_rule_names(self.rules)
