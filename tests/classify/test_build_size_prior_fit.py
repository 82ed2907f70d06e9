"""``fit_classifier_size_prior`` from Python: a classifier graph over the synthetic classes gets
a prior fitted on their training views, measured on the test views, and with ``write`` the
prior and that measurement in its card; a graph of other classes is refused."""

from __future__ import annotations

from pathlib import Path

import pytest
from cls_helpers import export_fixed

from itnet.model.classify.configs import SizePriorFitConfig
from itnet.model.classify.size_prior_fit import fit_classifier_size_prior
from itnet.model.input_error import InputError
from itnet.pose.runtime import LoadedClassifier, load_any


def test_the_prior_is_fitted_measured_and_written_into_the_card(
    three_classes: Path, tmp_path: Path
) -> None:
    classes = ["ball", "plate", "rod"]  # equal logits: only the size can tell them apart
    path = export_fixed(tmp_path, [0.0, 0.0, 0.0], classes=classes, points=64)
    config = SizePriorFitConfig(classifier=path, data=three_classes, split="test",
                                cache=tmp_path / "cache", rules="occluded")  # fmt: skip
    dry = fit_classifier_size_prior(config)
    assert dry.written is None and dry.current is None and dry.classes == classes
    assert dry.scores["views"] == 3 * 2 * 4 and 0 <= dry.scores["top1_with_size"] <= 1
    assert len(dry.prior.log_median) == 3 and dry.prior.df == 3.0 and dry.prior.weight == 0.5
    assert dry.prior.source.startswith(f"{three_classes.name} training split, 2 views a shape")
    assert dry.prior.evaluation.startswith("test views (24, 4 a shape, occluded views in turn")
    graph = load_any(path, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.size_prior is None
    written = fit_classifier_size_prior(config.model_copy(update={"write": True}))
    assert written.written == path and written.scores == dry.scores
    graph = load_any(path, warm_up=False)
    assert isinstance(graph, LoadedClassifier) and graph.card.size_prior == written.prior
    again = fit_classifier_size_prior(config)  # the card's prior, measured on the same views
    assert again.current == dry.scores


def test_a_classifier_of_other_classes_is_refused(three_classes: Path, tmp_path: Path) -> None:
    path = export_fixed(tmp_path, [1.0, 0.0, 0.0])  # chair, table, sofa
    config = SizePriorFitConfig(classifier=path, data=three_classes, cache=tmp_path / "cache")
    with pytest.raises(InputError, match="are not the card's"):
        fit_classifier_size_prior(config)
