"""The centre correction (itnet.centre): its features, its fit, and the engine applying it after
the last step where the card has one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from itnet.centre import (
    FEATURE_COUNT,
    CentreCorrection,
    centre_features,
    centre_finished,
    fit_centre_correction,
)
from itnet.pose.errors import BadCloudError
from itnet.pose.runtime import load_model
from itnet.preprocess import pose_from_normalized
from tests.pose_runs import run_with


def intercept_only(offset: list[float]) -> CentreCorrection:
    """A correction that predicts the same centre offset for every cloud."""
    weights = np.zeros((FEATURE_COUNT + 1, 3))
    weights[-1] = offset
    return CentreCorrection(np.zeros(FEATURE_COUNT), np.ones(FEATURE_COUNT), weights)


def test_features_describe_where_the_cloud_lies() -> None:
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(500, 3))
    f = centre_features(cloud)
    assert f.shape == (FEATURE_COUNT,)
    assert np.isclose(f[-64:].sum(), 1.0)  # every point in one grid cell (outliers at the border)
    shifted = centre_features(cloud + np.array([0.5, 0.0, 0.0]))
    assert np.allclose(shifted[15:18] - f[15:18], [0.5, 0, 0])  # the mean moves with the cloud
    with pytest.raises(ValueError):
        centre_features(np.zeros((0, 3)))


def test_the_fit_recovers_a_linear_map_and_round_trips_through_the_card() -> None:
    rng = np.random.default_rng(1)
    features = np.stack([centre_features(rng.normal(size=(200, 3)) * rng.uniform(0.5, 1.5, 3))
                         for _ in range(400)])  # fmt: skip
    truth = rng.normal(size=(FEATURE_COUNT, 3)) * 0.05
    offsets = features @ truth + [0.1, -0.2, 0.05]
    correction = fit_centre_correction(features, offsets, ridge=1e-6)
    z = (features - correction.mean) / correction.scale
    assert np.allclose(z @ correction.weights[:-1] + correction.weights[-1], offsets, atol=1e-3)
    again = CentreCorrection.from_dict(correction.to_dict())
    assert np.allclose(again.weights, correction.weights, atol=1e-5)
    with pytest.raises(ValueError):
        CentreCorrection(correction.mean, correction.scale, correction.weights[:-1])
    with pytest.raises(ValueError):
        CentreCorrection.from_dict({**correction.to_dict(), "features": "another-v9"})


def test_the_finished_pose_moves_the_predicted_centre_to_the_origin() -> None:
    pose = np.eye(4)
    pose[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    pose[:3, 3] = [0.3, 0.0, -0.1]
    points = np.random.default_rng(2).normal(size=(100, 3))
    done = centre_finished(points, pose, intercept_only([0.05, -0.02, 0.1]))
    assert np.allclose(done[:3, :3], pose[:3, :3])
    assert np.allclose(done[:3, 3], [0.25, 0.02, -0.2])


@pytest.fixture(scope="module")
def centred_model(tmp_path_factory: pytest.TempPathFactory, export_model):  # type: ignore[no-untyped-def]
    from itnet.model_card import ModelCard

    folder: Path = tmp_path_factory.mktemp("centre_models")
    card = ModelCard(
        name="tiny", category="chair", points=256, recommended_iterations=4,
        centre_correction=intercept_only([0.05, -0.02, 0.1]).to_dict(),
    )  # fmt: skip
    export_model(card, folder / "tiny.onnx")
    return load_model(folder / "tiny.onnx", threads=1)


def cloud() -> np.ndarray:
    return np.random.default_rng(3).normal(size=(400, 3)) * [0.5, 1.0, 0.3] + [2.0, -1.0, 4.0]


def test_the_engine_finishes_the_centre_by_the_card_and_says_so(centred_model) -> None:  # type: ignore[no-untyped-def]
    on = run_with(centred_model, cloud(), budget_ms=10_000, converge=(0, 0))
    off = run_with(centred_model, cloud(), budget_ms=10_000, converge=(0, 0), centre=False)
    on.run_to_end(), off.run_to_end()
    assert on.result()["centre"] is True and "centre" not in off.result()
    expected = pose_from_normalized(
        centre_finished(on.points[0], off.last.pose_normalized, centred_model.centre),
        off.normalization,
    )
    assert np.allclose(on.result()["T_canonical_from_input"], expected, atol=1e-5)
    moved = np.asarray(on.result()["translation"]) - np.asarray(off.result()["translation"])
    assert np.allclose(moved, -np.array([0.05, -0.02, 0.1]) * on.normalization.scale, atol=1e-5)


def test_no_correction_without_a_step_or_when_asked_not_to(centred_model) -> None:  # type: ignore[no-untyped-def]
    cancelled = run_with(centred_model, cloud(), budget_ms=10_000)
    cancelled.cancel()
    cancelled.run_to_end()
    assert cancelled.result()["centre"] is False and cancelled.iteration == 0
    off = run_with(centred_model, cloud(), budget_ms=10_000, centre=False)
    off.run_to_end()
    assert "centre" not in off.result()


def test_asking_for_a_correction_the_card_lacks_is_refused(tiny_model_dir: Path) -> None:
    plain = load_model(tiny_model_dir / "tiny.onnx", threads=1)
    with pytest.raises(BadCloudError, match="no centre correction"):
        run_with(plain, cloud(), budget_ms=50, centre=True)
    assert "centre" not in run_with(plain, cloud(), budget_ms=50).result()


@pytest.fixture(scope="module")
def viewpoint_model(tmp_path_factory: pytest.TempPathFactory, export_model):  # type: ignore[no-untyped-def]
    """A card with both corrections: the plain one predicts OFFSET, the viewpoint one predicts
    the direction toward the sensor (its last three features) times 0.1."""
    from itnet.centre import FEATURES_VIEWPOINT
    from itnet.model_card import ModelCard

    weights = np.zeros((FEATURE_COUNT + 4, 3))
    weights[FEATURE_COUNT : FEATURE_COUNT + 3] = 0.1 * np.eye(3)
    toward = CentreCorrection(
        np.zeros(FEATURE_COUNT + 3), np.ones(FEATURE_COUNT + 3), weights, FEATURES_VIEWPOINT
    )
    folder: Path = tmp_path_factory.mktemp("viewpoint_models")
    card = ModelCard(
        name="tiny", category="chair", points=256, recommended_iterations=3,
        centre_correction=intercept_only([0.05, -0.02, 0.1]).to_dict(),
        centre_correction_viewpoint=toward.to_dict(),
    )  # fmt: skip
    export_model(card, folder / "tiny.onnx")
    return load_model(folder / "tiny.onnx", threads=1)


def test_a_viewpoint_moves_the_centre_along_the_sensors_ray(viewpoint_model) -> None:  # type: ignore[no-untyped-def]
    sensor = np.array([0.0, 0.0, 0.0])  # the cloud sits around (2, -1, 4): the camera's frame
    run = run_with(viewpoint_model, cloud(), budget_ms=10_000, viewpoint=sensor)
    off = run_with(viewpoint_model, cloud(), budget_ms=10_000, centre=False)
    run.run_to_end(), off.run_to_end()
    result = run.result()
    assert result["centre"] is True and result["centre_viewpoint"] is True
    # the estimated centre (where T maps the origin of the canonical frame from) moves 0.1 RMS
    # radii away from the sensor... as the correction says: toward it is its offset's direction
    centre = lambda t: -np.asarray(t)[:3, :3].T @ np.asarray(t)[:3, 3]  # noqa: E731
    moved = centre(result["T_canonical_from_input"]) - centre(
        off.result()["T_canonical_from_input"]
    )
    ray = centre(off.result()["T_canonical_from_input"]) - sensor
    cos = moved @ ray / np.linalg.norm(moved) / np.linalg.norm(ray)
    assert np.isclose(np.linalg.norm(moved), 0.1 * run.normalization.scale, rtol=1e-3)
    assert cos < -0.999  # toward the sensor: the offset points at it, the pose moves it there
    plain = run_with(viewpoint_model, cloud(), budget_ms=10_000)
    plain.run_to_end()
    assert "centre_viewpoint" not in plain.result()


def test_a_bad_viewpoint_is_refused(viewpoint_model) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(BadCloudError, match="viewpoint"):  # the request's checks are pydantic's,
        run_with(viewpoint_model, cloud(), budget_ms=50, viewpoint=[0, np.nan, 1])  # finite: here
    for bad in ([0, 0], "here"):
        with pytest.raises((BadCloudError, ValueError), match="viewpoint"):
            run_with(viewpoint_model, cloud(), budget_ms=50, viewpoint=bad)


def test_a_card_with_only_a_viewpoint_correction_uses_it_only_with_a_viewpoint(
    tmp_path: Path, export_model, viewpoint_model
) -> None:  # type: ignore[no-untyped-def]

    card = viewpoint_model.card.model_copy(update={"centre_correction": None})
    export_model(card, tmp_path / "tiny.onnx")
    only = load_model(tmp_path / "tiny.onnx", threads=1)
    assert only.centre is None and only.centre_viewpoint is not None
    without = run_with(only, cloud(), budget_ms=10_000)
    without.run_to_end()
    assert "centre" not in without.result()
    given = run_with(only, cloud(), budget_ms=10_000, viewpoint=[0, 0, 0])
    given.run_to_end()
    assert given.result()["centre"] is True and given.result()["centre_viewpoint"] is True
    with pytest.raises(BadCloudError, match="no centre correction"):
        run_with(only, cloud(), budget_ms=50, centre=True)


def test_a_card_with_a_correction_of_the_wrong_kind_or_shape_fails_to_load(
    tmp_path: Path, export_model, viewpoint_model
) -> None:  # type: ignore[no-untyped-def]
    """Checked at load, not at the first request: the plain field holding a viewpoint correction
    (or the other way round), or a correction with the wrong shapes, is a ModelLoadError."""
    from itnet.pose.runtime import ModelLoadError

    card = viewpoint_model.card
    swapped = card.model_copy(update={"centre_correction": card.centre_correction_viewpoint,
                                      "centre_correction_viewpoint": card.centre_correction})  # fmt: skip
    broken = card.model_copy(
        update={"centre_correction": {**card.centre_correction, "weights": [[0.0, 0.0, 0.0]]}}
    )
    for name, bad in (("swapped", swapped), ("broken", broken)):
        export_model(bad, tmp_path / f"{name}.onnx")
        with pytest.raises(ModelLoadError, match="centre_correction"):
            load_model(tmp_path / f"{name}.onnx", threads=1)


def centre_moved(model, **request):  # type: ignore[no-untyped-def]
    """The reply of a run with the centre finish, and how far the finish moved the pose's
    translation (normalised units) against the same run without it."""
    on = run_with(model, cloud(), budget_ms=10_000, converge=(0, 0), **request)
    off = run_with(model, cloud(), budget_ms=10_000, converge=(0, 0), centre=False, **request)
    on.run_to_end(), off.run_to_end()
    moved = np.asarray(on.result()["translation"]) - np.asarray(off.result()["translation"])
    return on.result(), moved / on.normalization.scale


def test_a_request_that_gives_up_is_finished_by_the_upright_correction(
    tmp_path: Path, export_model, viewpoint_model
) -> None:  # type: ignore[no-untyped-def]
    """centre_correction_up: used where a request gives up (and no viewpoint the card has a
    correction for), the plain one otherwise; a card with only it (a model that requires up)
    finishes every request; the reply says which one did it; a bad one fails the load."""
    from itnet.pose.runtime import ModelLoadError

    up_offset = [-0.1, 0.0, 0.2]
    card = viewpoint_model.card.model_copy(
        update={"centre_correction_up": intercept_only(up_offset).to_dict()}
    )
    export_model(card, tmp_path / "all.onnx")
    model = load_model(tmp_path / "all.onnx", threads=1)
    assert model.centre_up is not None
    up = [0.0, 1.0, 0.0]

    given, moved = centre_moved(model, up=up)
    assert given["centre"] is True and given["centre_up"] is True
    assert np.allclose(moved, -np.array(up_offset), atol=1e-5)
    plain, moved = centre_moved(model)
    assert "centre_up" not in plain and np.allclose(moved, -np.array([0.05, -0.02, 0.1]), atol=1e-5)
    # the viewpoint's correction comes first
    both, _ = centre_moved(model, up=up, viewpoint=[0, 0, 0])
    assert both["centre_viewpoint"] is True and both["centre_up"] is False

    only = card.model_copy(
        update={"centre_correction": None, "centre_correction_viewpoint": None, "requires_up": True}
    )
    export_model(only, tmp_path / "only.onnx")
    upright = load_model(tmp_path / "only.onnx", threads=1)
    run = run_with(upright, cloud(), budget_ms=10_000, up=up)
    run.run_to_end()
    assert run.result()["centre"] is True and run.result()["centre_up"] is True

    wrong = card.model_copy(update={"centre_correction_up": card.centre_correction_viewpoint})
    export_model(wrong, tmp_path / "wrong.onnx")
    with pytest.raises(ModelLoadError, match="centre_correction_up"):
        load_model(tmp_path / "wrong.onnx", threads=1)


def test_a_request_with_up_and_a_viewpoint_is_finished_by_the_upright_viewpoint_correction(
    tmp_path: Path, export_model, viewpoint_model
) -> None:  # type: ignore[no-untyped-def]
    """centre_correction_up_viewpoint: used where a request gives both up and a viewpoint (the
    reply says centre_viewpoint and centre_up); a request with one of them gets its own; a
    correction without the sensor's direction in that field fails the load."""
    from itnet.centre import FEATURES_VIEWPOINT
    from itnet.pose.runtime import ModelLoadError

    weights = np.zeros((FEATURE_COUNT + 4, 3))
    weights[-1] = [0.0, 0.3, 0.0]  # a constant offset, unlike the fixture's two corrections
    held = CentreCorrection(
        np.zeros(FEATURE_COUNT + 3), np.ones(FEATURE_COUNT + 3), weights, FEATURES_VIEWPOINT
    )
    card = viewpoint_model.card.model_copy(
        update={
            "centre_correction_up": intercept_only([-0.1, 0.0, 0.2]).to_dict(),
            "centre_correction_up_viewpoint": held.to_dict(),
        }
    )
    export_model(card, tmp_path / "held.onnx")
    model = load_model(tmp_path / "held.onnx", threads=1)
    assert model.centre_up_viewpoint is not None and model.centre_up_viewpoint.uses_viewpoint

    up, viewpoint = [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]
    both, moved = centre_moved(model, up=up, viewpoint=viewpoint)
    assert both["centre_viewpoint"] is True and both["centre_up"] is True
    assert np.allclose(moved, [0.0, -0.3, 0.0], atol=1e-5)
    # the viewpoint correction of unheld runs
    alone, moved = centre_moved(model, viewpoint=viewpoint)
    assert alone["centre_viewpoint"] is True and not np.allclose(moved, [0.0, -0.3, 0.0], atol=1e-3)
    upright, moved = centre_moved(model, up=up)
    assert upright["centre_up"] is True and np.allclose(moved, [0.1, 0.0, -0.2], atol=1e-5)

    wrong = card.model_copy(
        update={"centre_correction_up_viewpoint": intercept_only([0.0, 0.1, 0.0]).to_dict()}
    )
    export_model(wrong, tmp_path / "wrong.onnx")
    with pytest.raises(ModelLoadError, match="centre_correction_up_viewpoint"):
        load_model(tmp_path / "wrong.onnx", threads=1)
