"""A known unit lets the cloud's size count toward its category (``itnet.size_prior``): the pure
math, and ``units`` through the recognition, HTTP and the CLI, with a classifier graph that
cannot tell a chair from a table by form (equal logits) and a size prior that can."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from cls_helpers import export_fixed
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from itnet.cli import app as cli
from itnet.model_card import SizePrior
from itnet.pose.errors import BadCloudError
from itnet.pose.recognition import classify
from itnet.pose.runtime import load_any
from itnet.preprocess import estimate_normalization
from itnet.service.app import create_app
from itnet.service.settings import Settings
from itnet.size_prior import fit_size_prior, metres_per_unit, size_log_likelihood, with_size

# chair, table, sofa: RMS radius of a view 0.3 m, 1.0 m, 2.0 m
PRIOR = SizePrior(log_median=[math.log(0.3), math.log(1.0), math.log(2.0)],
                  log_scale=[0.2, 0.2, 0.2], df=3.0, weight=0.5)  # fmt: skip


def test_units_are_metres_per_unit() -> None:
    assert metres_per_unit("m") == 1.0 and metres_per_unit("mm") == 0.001
    assert metres_per_unit("in") == pytest.approx(0.0254)
    with pytest.raises(ValueError, match="unknown unit 'furlong'"):
        metres_per_unit("furlong")


def test_size_likelihood_peaks_at_each_class_median_and_is_heavy_tailed() -> None:
    for k, median in enumerate(PRIOR.log_median):
        assert size_log_likelihood(PRIOR, math.exp(median)).argmax() == k
    near, far = size_log_likelihood(PRIOR, 0.3), size_log_likelihood(PRIOR, 0.3 * math.e**2)
    # ten spreads off in log size costs the chair far less than a Gaussian's 50 nats
    assert 3 < near[0] - far[0] < 12
    # an indifferent classifier follows the size; a sure one is not overruled by it
    assert with_size(np.log([0.5, 0.5, 1e-6]), PRIOR, 0.9).argmax() == 1
    assert with_size(np.log([0.999, 0.001, 1e-6]), PRIOR, 0.9).argmax() == 0


def test_fit_is_robust_to_models_at_another_scale(rng) -> None:
    labels = np.repeat([0, 1], 200)
    radii = np.exp(rng.normal(np.log([0.3, 1.0])[labels], 0.1))
    radii[:20] *= 2.54  # a tenth of the chairs drawn in centimetres read as inches
    prior = fit_size_prior(labels, radii, 2)
    assert np.allclose(np.exp(prior.log_median), [0.3, 1.0], rtol=0.05)
    assert 0.08 < prior.log_scale[0] < 0.2
    with pytest.raises(ValueError, match="class 2 has no views"):
        fit_size_prior(labels, radii, 3)


@pytest.fixture(scope="module")
def sized_dir(pose_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The chair pose model and a classifier that finds chair and table alike (p = 0.5 each)
    but knows their sizes."""
    import shutil

    folder = tmp_path_factory.mktemp("sized")
    shutil.copy(pose_dir / "chair.onnx", folder / "chair.onnx")
    export_fixed(folder, [0.0, 0.0, -8.0], 0.5, PRIOR)
    return folder


def cloud_of_size(rms_radius: float, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, size=(300, 3)) * [0.3, 0.5, 0.2]
    points *= rms_radius / estimate_normalization(points).scale
    return points + np.array([1.0, -2.0, 3.0])


def test_a_known_unit_lets_the_size_decide(sized_dir: Path) -> None:
    classifier = load_any(sized_dir / "classifier.onnx", warm_up=False)
    small, large = cloud_of_size(0.3), cloud_of_size(1.0)
    alone = classify(classifier, small)
    assert alone.size_m is None and not alone.size_used
    assert alone.probability == pytest.approx(0.5, abs=0.01)
    assert classify(classifier, small, units="m").category == "chair"
    assert classify(classifier, large, units="m").category == "table"
    in_mm = classify(classifier, small * 1000, units="mm")
    assert in_mm.category == "chair" and in_mm.size_m == pytest.approx(0.3, rel=1e-3)
    assert in_mm.probability > 0.9 and in_mm.as_dict()["size_used"] is True
    with pytest.raises(BadCloudError, match="unknown unit"):
        classify(classifier, small, units="furlong")


def test_a_unit_without_a_size_prior_is_reported_not_used(chair_dir: Path) -> None:
    classifier = load_any(chair_dir / "classifier.onnx", warm_up=False)
    result = classify(classifier, cloud_of_size(0.3), units="cm").as_dict()
    assert result["size_used"] is False and result["size_m"] == pytest.approx(0.003, rel=1e-3)


@pytest.fixture(scope="module")
def sized_client(sized_dir: Path) -> Iterator[TestClient]:
    with TestClient(create_app(Settings(model_dir=sized_dir, warm_up=False))) as client:
        yield client


def test_http_units(sized_client: TestClient) -> None:
    assert sized_client.get("/v1/models").json()["auto"]["sizes"] == ""  # a prior, unmeasured
    body = {"model": "auto", "budget_ms": 2000, "max_iterations": 2}
    reply = sized_client.post("/v1/estimate", json={**body, "points": cloud_of_size(0.3).tolist(),
                                                     "units": "m"})  # fmt: skip
    assert reply.status_code == 200, reply.text
    assert reply.json()["category"] == "chair" and reply.json()["size_used"] is True
    # the same cloud four times larger is a table, and no table pose model is loaded
    large = {**body, "points": (4 * cloud_of_size(0.3)).tolist(), "units": "m"}
    refused = sized_client.post("/v1/estimate", json=large)
    assert refused.status_code == 422 and refused.json()["kind"] == "no_pose_model"
    assert "table" in refused.json()["detail"]
    bad = sized_client.post("/v1/estimate", json={**large, "units": "furlong"})
    assert bad.status_code == 422 and "units" in bad.text
    # the pose does not depend on the unit
    named = {**body, "model": "chair", "points": cloud_of_size(0.3).tolist()}
    plain, with_units = (sized_client.post("/v1/estimate", json=named),
                         sized_client.post("/v1/estimate", json={**named, "units": "cm"}))  # fmt: skip
    assert plain.json()["T_canonical_from_input"] == with_units.json()["T_canonical_from_input"]


def test_cli_classify_units(sized_dir: Path, tmp_path: Path) -> None:
    path = tmp_path / "small.npy"
    np.save(path, cloud_of_size(0.3) * 100)  # centimetres
    args = ["classify", str(path), "--model-dir", str(sized_dir), "--json"]
    said = json.loads(CliRunner().invoke(cli, [*args, "--units", "cm"]).output)
    assert said["category"] == "chair" and said["size_used"] is True
    assert said["size_m"] == pytest.approx(0.3, rel=1e-3)
    # read as metres it is 30 m across: nearest the sofa's size, but the form rules the sofa
    # out (p = 0.0002) and the heavy tails keep an absurd size from overruling it
    absurd = json.loads(CliRunner().invoke(cli, [*args, "--units", "m"]).output)
    assert absurd["category"] == "table" and absurd["size_m"] == pytest.approx(30, rel=1e-3)
    refused = CliRunner().invoke(cli, [*args, "--units", "furlong"])
    assert refused.exit_code == 2 and "furlong" in refused.output


def test_views_at_real_sizes_measure_each_class_in_its_range_of_real_pieces() -> None:
    from itnet.model.categories import real_radius_m
    from itnet.model.classify.data import LabelledShapes
    from itnet.model.classify.size_prior import sized_views
    from itnet.model.shapes import Shape

    r = np.random.default_rng(3)
    ball = r.normal(size=(600, 3))
    ball /= np.linalg.norm(ball, axis=1, keepdims=True)  # a unit sphere: bounding radius 1
    shapes = LabelledShapes([Shape(f"s{i}", ball) for i in range(4)], np.array([0, 0, 1, 1]),
                            ("bed", "night_stand"))  # fmt: skip
    rules = ("occluded", "occluded+kinect_v2")
    views = sized_views(shapes, [1.0] * 4, 4, 0, 64, rules=rules, real=True)
    assert views.points is not None and views.points.shape == (16, 64, 3)
    for label, name in enumerate(("bed", "night_stand")):
        low, high = real_radius_m(name)
        own = views.radii_m[views.labels == label]
        # a partial view of a sphere: its RMS radius about its centroid under the sphere's
        assert (own > 0.2 * low).all() and (own < high).all(), (name, own)
    # the same shapes at their files' size in inches: 1 inch of bounding radius
    inches = sized_views(shapes, [1.0] * 4, 2, 0, rules=rules)
    assert (inches.radii_m < 0.0254).all()
    assert views.radii_m[views.labels == 0].mean() > 1.5 * views.radii_m[views.labels == 1].mean()


def test_the_size_prior_command_refuses_unknown_sizes_and_view_rules() -> None:
    runner = CliRunner()
    for args, hint in [(["--sizes", "feet"], "--sizes"), (["--rules", "sideways"], "sideways"),
                       (["--rules", "occluded+kinect_v9"], "kinect_v9")]:  # fmt: skip
        result = runner.invoke(cli, ["classify-size-prior", *args])
        assert result.exit_code == 2 and hint in result.output, result.output
