"""One classifier run from ``ClassifyTrainConfig``: the config turned into the run's
``ClassifyConfig`` (view rules and elevation parsed, the BatchNorm momentum's floor added),
then ``itnet.model.classify.train.train``.

    report = train_classifier(ClassifyTrainConfig(variant="tnet-2", out=Path("runs/tnet")))
    report.validation_accuracy, report.test        # 0.81, {"accuracy": 0.79, ...} or None
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from itnet.model.classify.configs import ClassifyTrainConfig
from itnet.model.classify.train import ClassifyConfig, train

BN_MOMENTUM_FLOOR = 0.01
"""Where the BatchNorm momentum stops halving."""

AS_GIVEN = (
    "data", "variant", "out", "steps", "lr", "decay_every", "init_from", "balanced", "up_weight",
    "stretch", "upright", "canonical_points", "label_smoothing", "ema", "hold_test", "head",
    "neighbours", "transformer_from", "freeze_transformer", "init_seed", "eval_every", "threads",
    "cache", "compile", "batch", "device", "data_workers",
)  # fmt: skip
"""The fields a ``ClassifyConfig`` takes as they are, under the same name."""


@dataclass(frozen=True)
class ClassifyTrainReport:
    """A finished run: its variant, torch's validation metrics of best.pt and its test metrics
    (None: held back, or no test shapes), and the whole ``result.json``."""

    variant: str
    validation: dict[str, Any]
    test: dict[str, Any] | None
    result: dict[str, Any] = field(default_factory=dict)

    @property
    def validation_accuracy(self) -> float:
        """Top-1 of best.pt on the validation views."""
        return float(self.validation["accuracy"])


def classify_config(config: ClassifyTrainConfig) -> ClassifyConfig:
    """The run's ``ClassifyConfig`` of ``config``."""
    return ClassifyConfig(
        **{name: getattr(config, name) for name in AS_GIVEN},
        bn_momentum=(config.bn_momentum, BN_MOMENTUM_FLOOR),
        views=config.view_rules(),
        elevation=config.elevation_range(),
    )


def train_classifier(config: ClassifyTrainConfig, log_progress: bool = True) -> ClassifyTrainReport:
    """Train (or resume) the run ``config`` asks for, into ``config.out``."""
    result = train(classify_config(config), log_progress=log_progress)
    return ClassifyTrainReport(config.variant, result["val"], result["test"], result)
