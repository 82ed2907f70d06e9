"""AlignRequest (one declaration for the CLI, HTTP and clients), both clouds posed as one
request, and the benchmark's pair generators."""

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from itnet.alignment.estimators import ALIGN_RUNS, cloud_request, in_process_estimator
from itnet.alignment.pipeline import POSE_SHARE, CloudEstimateError
from itnet.alignment.request import DEFAULT_BUDGET_MS, AlignRequest
from itnet.pose.catalog import Catalog
from itnet.pose.errors import OverloadedError
from itnet.pose.runtime import load_models

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "modelnet10"


def test_the_request_gives_each_cloud_its_share_and_the_pipeline_its_knobs(tiny_model_dir):
    request = AlignRequest(model="tiny", budget_ms=80, candidates=3, rivals=False, up_a=[0, 1, 0])
    pose = cloud_request(request.pose_request())
    assert pose.budget_ms == pytest.approx(80 * POSE_SHARE) and pose.ensemble == ALIGN_RUNS
    assert cloud_request(AlignRequest(starts=2).pose_request()).ensemble == 2
    assert cloud_request(AlignRequest(budget_ms=5000).pose_request()).ensemble == ALIGN_RUNS
    # each cloud's runs take every step (the choice was calibrated on them), unless asked
    assert pose.schedule is False
    scheduled = AlignRequest().pose_request().model_copy(update={"schedule": True})
    assert cloud_request(scheduled).schedule is True
    card = Catalog(load_models(tiny_model_dir, warm_up=False)).model("tiny").card
    options = request.options(card, refine=True)
    assert options.budget_ms == 80 and options.candidates == 3 and options.rivals is False
    assert options.refine is True and options.symmetry in ("none", "yaw180", "yaw90", "yaw")
    assert AlignRequest(symmetry="yaw180").options(card, False).symmetry == "yaw180"
    body = request.body(np.zeros((5, 3)), np.ones((6, 3)))
    assert len(body["points_a"]) == 5 and body["budget_ms"] == 80 and body["rivals"] is False
    assert AlignRequest().budget_ms == DEFAULT_BUDGET_MS
    # rivals by default where ICP refines them; unrefined, only where asked for
    assert AlignRequest().options(card, refine=True).rivals is True
    assert AlignRequest().options(card, refine=False).rivals is False
    assert AlignRequest(rivals=True).options(card, refine=False).rivals is True


BAD_FIELDS = [{"budget_ms": 0}, {"symmetry": "yaw45"}, {"starts": 17}, {"candidates": 0},
              {"up_a": [0, 1]}, {"colour": "red"}]  # fmt: skip


@pytest.mark.parametrize("bad", BAD_FIELDS)
def test_a_bad_field_is_refused_by_name(bad):
    with pytest.raises(ValidationError, match=next(iter(bad))):
        AlignRequest(**bad)


def test_both_clouds_are_admitted_as_one_request_and_share_one_clock(tiny_model_dir, rng):
    catalog = Catalog(load_models(tiny_model_dir, warm_up=False))
    estimate = in_process_estimator(
        catalog, AlignRequest(model="tiny", budget_ms=400).pose_request()
    )
    a, b = rng.normal(size=(300, 3)), rng.normal(size=(200, 3))
    started: list = []
    original = catalog.start

    def spy(points, request, at=None, **kw):
        started.append((request.budget_ms, at))
        return original(points, request, at, **kw)

    catalog.start = spy  # type: ignore[method-assign]
    pose_a, pose_b = estimate.together([a, b], [None, None])
    # A may end at half of the poses' share, B at all of it, both on one clock
    assert [s[0] for s in started] == pytest.approx([150.0, 300.0])
    assert started[0][1] == started[1][1] is not None
    assert pose_a.iterations > 0 and pose_b.iterations > 0 and len(pose_a.runs) == ALIGN_RUNS
    assert catalog.admission.running == 0  # both let go


def test_a_busy_machine_refuses_the_pair_naming_a_cloud(tiny_model_dir, rng):
    catalog = Catalog(load_models(tiny_model_dir, warm_up=False))
    estimate = in_process_estimator(
        catalog, AlignRequest(model="tiny", budget_ms=50).pose_request()
    )
    other = catalog.start(rng.normal(size=(100, 3)), AlignRequest(model="tiny").pose_request())
    with catalog.admission.admit(other):
        other.needed_work_ms = lambda: 1e6  # type: ignore[method-assign]
        with pytest.raises(CloudEstimateError) as refused:
            estimate.together([rng.normal(size=(100, 3))] * 2, [None, None])
    assert refused.value.cloud in ("A", "B")
    assert isinstance(refused.value.__cause__, OverloadedError)


@pytest.mark.skipif(not DATA.is_dir(), reason="ModelNet10 clouds not here")
def test_the_pair_generators_make_pairs_their_truth_aligns():
    from benchmarks.align_pairs import GENERATORS, make_pairs, overlap_of, split_shapes

    files = split_shapes(DATA, "table", "validation")[:3]
    for generator in GENERATORS:
        pairs = make_pairs(generator, files, 3, seed=1, category="table")
        for pair in pairs:
            assert pair.generator == generator and len(pair.a) >= 64 and len(pair.b) >= 64
            assert pair.truths.shape == (2, 4, 4)  # the table's half turn
            assert pair.right(pair.truth) and pair.right(pair.truths[1])
            assert not pair.right(pair.truth @ np.diag([1.0, -1.0, -1.0, 1.0]))  # upside down
            assert 0.0 <= overlap_of(pair) <= 1.0
    with pytest.raises(ValueError, match="unknown pair generator"):
        make_pairs("lidar", files, 1, 0, "table")


@pytest.mark.skipif(not DATA.is_dir(), reason="ModelNet10 clouds not here")
def test_a_generator_by_a_named_camera_makes_its_views_by_that_camera():
    """``sensor``: the same views by a depth camera (noise, flying pixels) at real size; the
    truth still aligns them. An unknown camera is refused."""
    from benchmarks.align_pairs import generator_config, make_pairs, split_shapes

    files = split_shapes(DATA, "chair", "validation")[:2]
    assert generator_config("paper", "chair", "kinect_v2").sensor == "kinect_v2"
    assert generator_config("paper", "chair").sensor != "kinect_v2"
    clean = make_pairs("paper", files, 2, seed=3, category="chair")
    sensed = make_pairs("paper", files, 2, seed=3, category="chair", sensor="kinect_v2")
    for a, b in zip(clean, sensed, strict=True):
        assert b.right(b.truth) and not np.array_equal(a.a, b.a)
    with pytest.raises(ValueError, match="unknown sensor"):
        make_pairs("paper", files, 1, 0, "chair", sensor="lidar")
