"""The upright classifier: loaded beside the classifier for any orientation, and for clouds whose
up is known fused with it (its input levelled, its looks turned about +y); said in the reply and
in GET /v1/models; refused alone, twice, or with other classes. Fixed-answer classifiers tell
whether it took part."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from cls_helpers import export_fixed
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from itnet.cli import app
from itnet.pose.recognition import classify, classify_together, turned_looks
from itnet.pose.runtime import ModelLoadError, load_all
from itnet.service.app import create_app
from itnet.service.settings import Settings
from itnet.upright import UP, unit_up

UP_GIVEN = [0.2, -1.0, 0.1]


@pytest.fixture(scope="module")
def both_dir(pose_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The chair pose model; a classifier that says 'table' (no table model), and an upright
    one that says 'chair' more strongly (the two fused: chair)."""
    folder = tmp_path_factory.mktemp("upright_pair")
    shutil.copy(pose_dir / "chair.onnx", folder / "chair.onnx")
    export_fixed(folder, [0.0, 6.0, 1.0], 0.5)
    export_fixed(folder, [12.0, 0.0, 1.0], 0.5, upright=True)
    return folder


def test_the_upright_classifier_rides_on_the_other_and_answers_when_up_is_given(
    both_dir: Path, box_cloud: np.ndarray
) -> None:
    _, classifier = load_all(both_dir, warm_up=False)
    assert classifier is not None and not classifier.card.upright
    assert classifier.upright is not None and classifier.upright.card.upright
    free = classify(classifier, box_cloud)
    assert free.category == "table" and not free.upright
    assert "classified_upright" not in free.as_dict()
    stood = classify(classifier, box_cloud, up=UP_GIVEN, looks=4)
    assert stood.category == "chair" and stood.upright and stood.looks == 4
    # the mean log-probability of the two: chair (12 + 0) / 2 against table (0 + 6) / 2
    logits = np.array([12.0, 6.0, 2.0]) / 2
    want = np.exp(logits - logits.max()) / np.exp(logits - logits.max()).sum()
    assert np.isclose(stood.probability, want[0], atol=1e-4)
    assert stood.as_dict()["classified_upright"] is True
    # both clouds of an alignment need their up for the upright one; else the free one answers
    assert (
        classify_together(classifier, [box_cloud, box_cloud], ups=[UP_GIVEN, None]).upright is False
    )
    assert classify_together(classifier, [box_cloud] * 2, ups=[UP_GIVEN, [0, 0, 1]]).upright


def test_without_an_upright_classifier_the_up_does_not_enter(chair_dir: Path, box_cloud) -> None:
    _, classifier = load_all(chair_dir, warm_up=False)
    assert classifier is not None and classifier.upright is None
    assert not classify(classifier, box_cloud, up=UP_GIVEN).upright


def test_a_bad_up_for_the_upright_classifier_is_a_bad_cloud(both_dir: Path, box_cloud) -> None:
    from itnet.pose.errors import BadCloudError

    _, classifier = load_all(both_dir, warm_up=False)
    with pytest.raises(BadCloudError, match="zero vector"):
        classify(classifier, box_cloud, up=[0, 0, 0])
    with pytest.raises(BadCloudError, match="1 up directions for 2 clouds"):
        classify_together(classifier, [box_cloud, box_cloud], ups=[UP_GIVEN])


def test_an_upright_classifier_alone_twice_or_with_other_classes_is_refused(
    pose_dir: Path, tmp_path: Path
) -> None:
    shutil.copy(pose_dir / "chair.onnx", tmp_path / "chair.onnx")
    export_fixed(tmp_path, [6.0, 0.0, 0.0], upright=True)
    with pytest.raises(ModelLoadError, match="serves only beside"):
        load_all(tmp_path, warm_up=False)
    export_fixed(tmp_path, [6.0, 0.0, 0.0])
    shutil.copy(tmp_path / "classifier_upright.onnx", tmp_path / "second_upright.onnx")
    with pytest.raises(ModelLoadError, match="more than one upright classifier"):
        load_all(tmp_path, warm_up=False)
    (tmp_path / "second_upright.onnx").unlink()
    export_fixed(tmp_path, [1.0, 0.0, 0.0], upright=True, classes=["mug", "cup", "bowl"])
    with pytest.raises(ModelLoadError, match="are not the other's"):
        load_all(tmp_path, warm_up=False)


def test_levelled_looks_stand_the_cloud_up_and_turn_about_y() -> None:
    rng = np.random.default_rng(0)
    up = unit_up(UP_GIVEN)
    rod = np.outer(rng.uniform(-1, 1, 400), up) + rng.normal(scale=0.02, size=(400, 3))
    looks = turned_looks(rod, 4, 128, rng, up=up)
    for look in looks:
        _, _, vt = np.linalg.svd(look - look.mean(0), full_matrices=False)
        assert abs(vt[0] @ UP) > 0.99  # the rod stands along +y in every look
    plain = turned_looks(rod, 4, 128, rng)
    _, _, vt = np.linalg.svd(plain[0] - plain[0].mean(0), full_matrices=False)
    assert abs(vt[0] @ UP) < 0.99  # without up it lies as it came


def test_auto_with_up_through_the_service_and_the_cli(both_dir: Path, box_cloud) -> None:
    settings = Settings(model_dir=both_dir)
    points = box_cloud.tolist()
    with TestClient(create_app(settings)) as client:
        free = client.post("/v1/estimate", json={"points": points, "model": "auto"})
        assert free.status_code == 422 and "looks like a table" in free.json()["detail"]
        stood = client.post(
            "/v1/estimate",
            json={"points": points, "model": "auto", "up": UP_GIVEN, "budget_ms": 5000},
        )
        assert stood.status_code == 200, stood.text
        reply = stood.json()
        assert reply["category"] == "chair" and reply["classified_upright"] is True
        assert np.allclose(
            np.asarray(reply["T_canonical_from_input"])[:3, :3] @ unit_up(UP_GIVEN), UP, atol=1e-4
        )
        auto = client.get("/v1/models").json()["auto"]
        assert auto["upright"] is not None and auto["upright"]["accuracy"] == 0.9
    path = both_dir / "box.npy"
    np.save(path, box_cloud)
    out = CliRunner().invoke(
        app, ["classify", str(path), "--model-dir", str(both_dir), "--up", "0.2,-1,0.1", "--json"]
    )
    assert out.exit_code == 0, out.output
    assert '"classified_upright": true' in out.output and '"category": "chair"' in out.output
    listed = CliRunner().invoke(app, ["models", "--model-dir", str(both_dir)])
    assert listed.exit_code == 0 and "an upright classifier joins it" in listed.output


@pytest.mark.parametrize("up", [None, UP_GIVEN])
def test_looks_normalise_only_the_points_they_keep_and_match_normalising_first(up) -> None:
    """``norm`` given: the raw cloud's subsets are normalised alone; the looks are those of the
    cloud normalised whole (the same draws, the same values), levelled or not."""
    from itnet.preprocess import estimate_normalization

    cloud = np.random.default_rng(1).normal(size=(900, 3)) * [3.0, 1.0, 0.2] + [40.0, -7.0, 2.0]
    norm = estimate_normalization(cloud)
    up = None if up is None else unit_up(up)
    whole = turned_looks(norm.apply(cloud), 4, 128, np.random.default_rng(3), up)
    kept = turned_looks(cloud, 4, 128, np.random.default_rng(3), up, norm)
    assert kept.dtype == np.float32 and kept.shape == (4, 128, 3)
    np.testing.assert_array_equal(kept, whole)
