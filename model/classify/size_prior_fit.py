"""The classifier's size prior from ``SizePriorFitConfig``: fitted on views of the training
shapes, measured with and without it on views of the validation or test shapes (4 a shape,
seeded; ``size_prior.accuracy_with_and_without``), and with ``write`` stored in the
classifier's card with that measurement as its evaluation, so that a request giving its
cloud's unit (``units``) lets the size count (``itnet.size_prior``).

    report = fit_classifier_size_prior(SizePriorFitConfig(sizes="real", split="test"))
    report.scores["top1_with_size"], report.written          # 0.87, False
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from itnet.model.classify.configs import SizePriorFitConfig
from itnet.model.classify.data import class_names, load_splits
from itnet.model.classify.size_prior import (
    accuracy_with_and_without,
    sized_views,
    source_radii,
)
from itnet.model.input_error import InputError
from itnet.model_card import SizePrior
from itnet.pose.runtime import LoadedClassifier, load_any
from itnet.size_prior import fit_size_prior

MEASURED_VIEWS = 4
"""Views per validation or test shape the prior is measured on."""
SPLIT_SEEDS = {"val": 2, "test": 3}
"""The seed of each split's measuring views (the fit's: 1)."""


@dataclass(frozen=True)
class SizePriorFitReport:
    """A fitted prior and its measurement: the classes, the prior (with its evaluation where it
    was written), the split measured, top-1 and mean class accuracy with and without it
    (``accuracy_with_and_without``), the card's prior before on the same views (None: it had
    none), and the classifier whose card was written (None: not written)."""

    classes: list[str]
    prior: SizePrior
    split: str
    scores: dict[str, float]
    current: dict[str, float] | None
    written: Path | None


def fit_classifier_size_prior(config: SizePriorFitConfig) -> SizePriorFitReport:
    """Fit and measure the size prior of ``config.classifier`` on ``config.data``, and with
    ``config.write`` store it in the classifier's card. Raises InputError where the file is
    not a classifier or the data's classes are not its card's."""
    loaded = load_any(config.classifier, warm_up=False)
    if not isinstance(loaded, LoadedClassifier):
        raise InputError(f"{config.classifier} is not a classifier")
    classes = class_names(config.data)
    if classes != list(loaded.card.classes):
        raise InputError(f"{config.data}'s classes {classes} are not the card's")
    splits = load_splits(config.data, classes, 0.1, 0, config.cache)
    rules, real = config.view_rules(), config.sizes == "real"
    training = sized_views(
        splits["train"], source_radii(config.data, classes, "train"), config.views, seed=1,
        rules=rules, real=real,
    )  # fmt: skip
    prior = fit_size_prior(training.labels, training.radii_m, len(classes), config.df,
                           config.weight, source=fit_source(config))  # fmt: skip
    measured = sized_views(
        splits[config.split], source_radii(config.data, classes, config.split), MEASURED_VIEWS,
        SPLIT_SEEDS[config.split], loaded.card.points, rules=rules, real=real,
    )  # fmt: skip
    scores = accuracy_with_and_without(loaded, measured, prior)
    current = None
    if loaded.card.size_prior is not None:  # what it would replace, on the same views
        current = accuracy_with_and_without(loaded, measured, loaded.card.size_prior)
    prior = prior.model_copy(update={"evaluation": evaluation(config, scores)})
    if config.write:
        write_prior(loaded, prior, config.classifier)
    written = config.classifier if config.write else None
    return SizePriorFitReport(classes, prior, config.split, scores, current, written)


def fit_source(config: SizePriorFitConfig) -> str:
    """The prior's ``source``: the data, views and sizes it was fitted on."""
    kinds = ", ".join(config.view_rules())
    at = (
        "at real sizes (docs/training.md#real-sizes)"
        if config.sizes == "real"
        else "its units read as inches"
    )
    return f"{config.data.name} training split, {config.views} views a shape ({kinds} views), {at}"


def evaluation(config: SizePriorFitConfig, scores: dict[str, float]) -> str:
    """The prior's ``evaluation``: ``scores`` (``accuracy_with_and_without``) and the views
    they were measured on."""
    kinds = ", ".join(config.view_rules())
    sizes = "at real sizes" if config.sizes == "real" else "in inches"
    return (
        f"{config.split} views ({scores['views']}, {MEASURED_VIEWS} a shape, {kinds} views in "
        f"turn, {sizes}): top-1 {100 * scores['top1']:.1f}% alone, "
        f"{100 * scores['top1_with_size']:.1f}% with the size (paired gain "
        f"{100 * scores['gain']:+.1f} ± {100 * scores['gain_stderr']:.1f}); mean class "
        f"{100 * scores['mean_class']:.1f}% -> {100 * scores['mean_class_with_size']:.1f}%"
    )


def write_prior(loaded: LoadedClassifier, prior: SizePrior, path: Path) -> Path:
    """Store ``prior`` in the card of the classifier graph at ``path`` (``loaded``)."""
    import onnx

    from itnet.export.onnx_export import save_with_card

    card = loaded.card.model_copy(update={"size_prior": prior})
    return save_with_card(onnx.load(str(path)), card, path)
