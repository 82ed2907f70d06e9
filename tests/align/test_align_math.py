"""Relative poses, hypotheses, overlap scores, the calibrated choice and the pipeline (no model,
no open3d)."""

import numpy as np
import pytest

from itnet.alignment.choice import (
    FEATURES,
    Calibration,
    choose,
    feature_row,
    fit_logistic,
    probability,
    shipped,
    support,
)
from itnet.alignment.hypotheses import (
    Hypothesis,
    build_hypotheses,
    distinct,
    relative_pose,
    same_alignment,
    symmetry_rotations,
    yaw_sweep,
)
from itnet.alignment.overlap import Cloud, overlap, overlap_score
from itnet.alignment.pipeline import (
    AlignOptions,
    CloudEstimateError,
    PoseEstimate,
    align_clouds,
)
from itnet.geometry import (
    apply_rigid,
    axis_angle_to_matrix,
    invert_rigid,
    random_rotation,
    rigid_from_rotation_translation,
    rotation_error_deg,
)


def random_pose(rng, size=None, scale=2.0):
    shape = () if size is None else (size,)
    return rigid_from_rotation_translation(
        random_rotation(rng, size), rng.normal(scale=scale, size=(*shape, 3))
    )


def asymmetric_object(rng, n=600):
    """Points of an L-shaped, lopsided object (canonical frame): no rotation maps it onto itself."""
    base = rng.uniform([-1, -0.1, -0.6], [1, 0.1, 0.6], size=(n // 2, 3))
    post = rng.uniform([0.6, 0.1, -0.6], [1, 1.2, -0.3], size=(n - n // 2, 3))
    return np.concatenate([base, post])


def test_relative_pose_moves_a_onto_b(rng):
    canonical = rng.normal(size=(100, 3))
    t_ca, t_cb = random_pose(rng), random_pose(rng)
    points_a = apply_rigid(invert_rigid(t_ca), canonical)  # the same points seen in frame a
    points_b = apply_rigid(invert_rigid(t_cb), canonical)
    b_from_a = relative_pose(t_ca, t_cb)
    assert np.allclose(apply_rigid(b_from_a, points_a), points_b, atol=1e-9)
    # Round trips: a->b->a is the identity, and swapping the roles inverts the transform.
    assert np.allclose(relative_pose(t_cb, t_ca) @ b_from_a, np.eye(4), atol=1e-9)
    assert np.allclose(relative_pose(t_cb, t_ca), invert_rigid(b_from_a), atol=1e-9)
    assert np.allclose(relative_pose(t_ca, t_ca), np.eye(4), atol=1e-9)


def test_relative_pose_batches(rng):
    t_ca, t_cb = random_pose(rng, 7), random_pose(rng, 7)
    batched = relative_pose(t_ca, t_cb)
    assert batched.shape == (7, 4, 4)
    for i in range(7):
        assert np.allclose(batched[i], relative_pose(t_ca[i], t_cb[i]))


@pytest.mark.parametrize(("name", "count"), [("none", 0), ("yaw180", 1), ("yaw90", 3)])
def test_symmetry_rotations_turn_about_up(name, count):
    syms = symmetry_rotations(name)
    assert syms.shape == (count, 4, 4)
    up = np.array([0.0, 1.0, 0.0])
    for s in syms:
        assert np.allclose(s[:3, :3] @ up, up)  # +y stays up
        assert np.allclose(s[:3, 3], 0)
        assert np.allclose(s[:3, :3] @ s[:3, :3].T, np.eye(3))
    with pytest.raises(ValueError, match="unknown symmetry"):
        symmetry_rotations("mirror")


def test_symmetric_hypothesis_recovers_a_pose_flipped_about_up(rng):
    t_ca, t_cb = random_pose(rng), random_pose(rng)
    flip = symmetry_rotations("yaw180")[0]
    truth = relative_pose(t_ca, t_cb)
    # IT-Net took A's front for its back: its estimate is off by the flip.
    hyps = build_hypotheses([flip @ t_ca], [t_cb], symmetry_rotations("yaw180"))
    assert [h.source for h in hyps] == ["itnet", "itnet+yaw180"]
    quarter = build_hypotheses([t_ca], [t_cb], symmetry_rotations("yaw90"))
    assert [h.source for h in quarter] == ["itnet", *(f"itnet+yaw{a}" for a in (90, 180, 270))]
    assert rotation_error_deg(hyps[0].T_b_from_a[:3, :3], truth[:3, :3]) > 170
    assert np.allclose(hyps[1].T_b_from_a, truth, atol=1e-9)


def test_hypotheses_cross_every_run_of_a_with_every_run_of_b(rng):
    poses_a, poses_b = random_pose(rng, 2), random_pose(rng, 3)
    flip = symmetry_rotations("yaw180")
    hyps = build_hypotheses(poses_a, poses_b, flip)
    assert len(hyps) == 2 * 3 * 2
    assert [h.source for h in hyps[:4]] == [
        "itnet",
        "itnet+yaw180",
        "itnet a0 b1",
        "itnet a0 b1+yaw180",
    ]
    assert hyps[-1].source == "itnet a1 b2+yaw180"
    assert np.allclose(hyps[-1].T_b_from_a, invert_rigid(poses_b[2]) @ flip[0] @ poses_a[1])
    assert np.allclose(hyps[2].T_b_from_a, relative_pose(poses_a[0], poses_b[1]))


def test_distinct_keeps_the_best_of_each_group_of_near_copies(rng):
    def turned(deg, shift=0.0):
        rot = axis_angle_to_matrix([0, 1, 0], np.radians(deg))
        return Hypothesis(rigid_from_rotation_translation(rot, [shift, 0, 0]), f"{deg}/{shift}")

    hyps = [turned(0), turned(20), turned(90), turned(100), turned(0, 1.0), turned(200)]
    scores = [0.5, 0.9, 0.3, 0.4, 0.6, 0.1]
    # 20 beats its near copy 0; 100 beats 90; the shifted copy of 0 is its own alignment.
    assert distinct(hyps, scores, count=10, scale=1.0) == [1, 4, 3, 5]
    assert distinct(hyps, scores, count=2, scale=1.0) == [1, 4]
    assert distinct(hyps, scores, count=10, scale=1.0, max_deg=5.0) == [1, 4, 0, 3, 2, 5]
    assert distinct(hyps, scores, count=10, scale=10.0) == [1, 3, 5]  # 1.0 is now near


def test_same_alignment_thresholds():
    shifted = np.eye(4)
    shifted[0, 3] = 0.04
    assert same_alignment(np.eye(4), shifted, scale=1.0)
    assert not same_alignment(np.eye(4), shifted, scale=0.5)  # 0.04 > 0.05 x 0.5
    turned = rigid_from_rotation_translation(axis_angle_to_matrix([0, 0, 1], np.radians(6)), 0)
    assert not same_alignment(np.eye(4), turned, scale=1.0)


def test_overlap_matches_a_direct_search_for_every_pose(rng):
    a, b = rng.normal(size=(80, 3)), rng.normal(size=(120, 3))
    poses = random_pose(rng, 5, scale=0.3)
    fitness, rmse = overlap(poses, Cloud(a), Cloud(b), distance=0.4)
    for pose, fit, err in zip(poses, fitness, rmse):
        moved = apply_rigid(pose, a)
        d_ab = np.array([np.linalg.norm(b - p, axis=1).min() for p in moved])
        d_ba = np.array([np.linalg.norm(moved - q, axis=1).min() for q in b])
        near = np.concatenate([d_ab[d_ab < 0.4], d_ba[d_ba < 0.4]])
        assert fit == pytest.approx(0.5 * (np.mean(d_ab < 0.4) + np.mean(d_ba < 0.4)))
        assert err == pytest.approx(np.sqrt(np.mean(near**2)))


def test_overlap_score(rng):
    cloud = rng.normal(size=(300, 3))
    pose = random_pose(rng)
    moved = apply_rigid(pose, cloud)
    fitness, rmse = overlap_score(cloud, moved, pose, inlier_distance=0.05)
    assert fitness == 1.0 and rmse < 1e-5
    far = rigid_from_rotation_translation(np.eye(3), [100.0, 0, 0]) @ pose
    assert overlap_score(cloud, moved, far, 0.05) == (0.0, float("inf"))
    # Half of A seen by B: half of each side has a partner.
    fitness, _ = overlap_score(cloud, moved[:150], pose, 1e-3)
    assert fitness == pytest.approx(0.75)


def test_choose_keeps_the_composed_pose_unless_a_rival_is_more_likely_right():
    assert choose([0.6, 0.7, 0.2]) == 1
    assert choose([0.7, 0.7]) == 0  # a tie is no reason to leave the composed pose
    assert choose([0.9, 0.5]) == 0


def test_the_shipped_calibration_trusts_fit_and_the_runs_agreement():
    weights = dict(zip(FEATURES, shipped().weights))
    assert len(shipped().weights) == len(FEATURES) and shipped().fitted_on
    assert weights["fitness"] > 0 and weights["support"] > 0 and weights["gain"] > 0
    composed = feature_row(0.6, 0.9, 1.0, True, False, 0.2, 0.0)
    worse = feature_row(0.3, 0.9, 1.0, True, False, 0.2, 0.0)
    alone = feature_row(0.6, 0.9, 0.0, True, False, 0.2, 0.0)  # no run backs it
    p = probability(np.stack([composed, worse, alone]))
    assert p[0] > p[1] and p[0] > p[2] and ((p > 0) & (p < 1)).all()


def test_support_counts_the_run_pairs_that_back_a_candidate(rng):
    pose = random_pose(rng, scale=0.1)  # 5 degrees about the origin move it by under 0.15
    turn = rigid_from_rotation_translation(axis_angle_to_matrix([0, 1, 0], np.radians(90)), 0)
    near = rigid_from_rotation_translation(axis_angle_to_matrix([0, 1, 0], np.radians(5)), 0)
    runs = np.stack([pose, near @ pose, turn @ pose, pose])
    got = support(np.stack([pose, turn @ pose]), runs, scale=1.0)
    assert got.tolist() == [0.75, 0.25]


def test_fit_logistic_recovers_the_weights_it_was_drawn_from(rng):
    x = np.column_stack([np.ones(4000), rng.normal(size=(4000, 2))])
    truth = np.array([-0.5, 2.0, -1.0])
    y = rng.random(4000) < 1 / (1 + np.exp(-x @ truth))
    assert np.allclose(fit_logistic(x, y, l2=1e-6), truth, atol=0.2)


def test_a_calibration_reads_back_what_it_wrote(tmp_path):
    fitted = Calibration(np.arange(len(FEATURES), dtype=float) / 10, "test pairs")
    fitted.write(tmp_path / "c.json", command="python -m x")
    again = Calibration.read(tmp_path / "c.json")
    assert np.allclose(again.weights, fitted.weights) and again.fitted_on == "test pairs"
    (tmp_path / "bad.json").write_text('{"features": ["bias"], "weights": [1.0]}')
    with pytest.raises(ValueError, match="features"):
        Calibration.read(tmp_path / "bad.json")


def fake_estimator(clouds_and_poses, calls):
    """An estimator that knows each cloud's pose: the same answer from every start (as a perfect
    IT-Net would give). It recognises a subset of a cloud by its first point."""

    def estimate(points, up=None):
        calls.append(len(points))
        for cloud, pose in clouds_and_poses:
            if len(points) >= 3 and (cloud == points[0]).all(axis=1).any():
                return PoseEstimate(pose, 4, 1.0, "max_iterations")
        raise ValueError("3 points is too few")

    return estimate


def flipped_pair(rng):
    """Clouds A, B of one lopsided object, and an estimator that reads A turned 180 degrees about
    up (B right): the case the symmetry hypotheses are for."""
    obj = asymmetric_object(rng)
    t_ca, t_cb = random_pose(rng), random_pose(rng)
    a, b = apply_rigid(invert_rigid(t_ca), obj), apply_rigid(invert_rigid(t_cb), obj)
    flip = symmetry_rotations("yaw180")[0]
    calls: list[int] = []
    estimate = fake_estimator([(a, flip @ t_ca), (b, t_cb)], calls)
    return a, b, relative_pose(t_ca, t_cb), estimate, calls


def test_a_composed_pose_in_doubt_loses_to_a_rival_more_likely_right(rng):
    a, b, truth, estimate, calls = flipped_pair(rng)
    result = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw180"))
    assert calls == [len(a), len(b)]  # each cloud's served pose, once
    assert result.iterations == 8 and result.considered == 2
    composed, flipped = result.hypotheses  # the composed pose always first
    assert composed.source == "itnet" and flipped.source == "itnet+yaw180"
    assert composed.probability < flipped.probability  # A lands on B only turned
    assert result.chosen == 1 and np.allclose(result.T_b_from_a, truth, atol=1e-9)
    assert flipped.loose_fitness > 0.95 > 0.5 > composed.loose_fitness
    reply = result.to_dict()
    assert reply["hypothesis"] == "itnet+yaw180" and reply["refined"] is False
    assert reply["probability"] == pytest.approx(flipped.probability, abs=1e-4)
    assert reply["runner_up"]["hypothesis"] == "itnet"
    assert reply["icp_distance"] == 0 and reply["considered"] == 2


def test_without_rivals_the_composed_pose_stands(rng):
    a, b, _, estimate, _ = flipped_pair(rng)
    result = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw180", rivals=False))
    assert len(result.hypotheses) == 1 and result.chosen == 0 and result.considered == 0


def test_composed_poses_are_the_answer_where_no_rival_fits_better(rng):
    obj = asymmetric_object(rng)
    t_ca, t_cb = random_pose(rng), random_pose(rng)
    a, b = apply_rigid(invert_rigid(t_ca), obj), apply_rigid(invert_rigid(t_cb), obj)
    estimate = fake_estimator([(a, t_ca), (b, t_cb)], [])
    result = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw90"))
    assert result.chosen == 0 and result.hypotheses[0].source == "itnet"
    assert np.allclose(result.T_b_from_a, relative_pose(t_ca, t_cb), atol=1e-9)
    # A sure composed pose is answered as it is: no rival judged.
    assert result.probability >= 0.9 and result.considered == 0 and len(result.hypotheses) == 1
    assert result.to_dict()["runner_up"] is None


def test_align_clouds_names_the_cloud_that_failed(rng):
    a = rng.normal(size=(50, 3))
    estimate = fake_estimator([(a, np.eye(4))], [])
    with pytest.raises(CloudEstimateError, match="cloud B: 3 points is too few") as info:
        align_clouds(a, rng.normal(size=(3, 3)), estimate, AlignOptions())
    assert info.value.cloud == "B" and isinstance(info.value.__cause__, ValueError)


def test_each_cloud_is_posed_with_its_own_up(rng):
    calls: list = []

    def estimate(points, up=None):
        calls.append(up)
        return PoseEstimate(np.eye(4), 10, 0.1, "max_iterations")

    a, b = rng.normal(size=(300, 3)), rng.normal(size=(50, 3))
    align_clouds(a, b, estimate, AlignOptions(symmetry="none"), up_a=[0, 0, 3], up_b=None)
    assert np.allclose(calls[0], [0, 0, 1]) and calls[1] is None
    with pytest.raises(ValueError, match="zero vector"):
        align_clouds(a, b, estimate, AlignOptions(), up_a=[0, 0, 0])
    with pytest.raises(ValueError, match="candidates"):
        align_clouds(a, b, estimate, AlignOptions(candidates=0))


def test_two_poses_held_upright_are_always_in_doubt(rng):
    """With each cloud's up given, the rivals are judged even where the composed pose is sure:
    the calibration saw no pair of poses held upright."""
    obj = asymmetric_object(rng)
    t_ca, t_cb = random_pose(rng), random_pose(rng)
    a, b = apply_rigid(invert_rigid(t_ca), obj), apply_rigid(invert_rigid(t_cb), obj)
    estimate = fake_estimator([(a, t_ca), (b, t_cb)], [])
    plain = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw90"))
    assert plain.probability >= 0.9 and plain.considered == 0
    ups = (
        invert_rigid(t_ca)[:3, :3] @ [0.0, 1.0, 0.0],
        invert_rigid(t_cb)[:3, :3] @ [0.0, 1.0, 0.0],
    )
    held = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw90"), up_a=ups[0], up_b=ups[1])
    assert held.considered > 0 and len(held.hypotheses) > 1
    assert held.chosen == 0 and np.allclose(held.T_b_from_a, relative_pose(t_ca, t_cb), atol=1e-9)


def test_a_yaw_sweep_turns_the_composed_pose_about_b_up_and_meets_the_centroids(rng):
    composed = rigid_from_rotation_translation(random_rotation(rng), [0.2, -1.0, 3.0])
    up_b = random_rotation(rng)[:, 1]
    ca, cb = rng.normal(size=3), rng.normal(size=3)
    swept = yaw_sweep(composed, up_b, ca, cb, 8)
    assert len(swept) == 8 and all(h.turned and not h.served for h in swept)
    # every prefix spreads round the circle: the half turn second, the quarter turns next
    assert [h.source for h in swept] == [
        f"sweep yaw{d}" for d in (0, 180, 90, 270, 45, 135, 225, 315)
    ]
    assert np.allclose(swept[0].T_b_from_a[:3, :3], composed[:3, :3])
    up_a = composed[:3, :3].T @ up_b  # the up the composed pose carries onto B's
    for h in swept:
        k = int(h.source.removeprefix("sweep yaw")) // 45
        rotation = h.T_b_from_a[:3, :3]
        assert np.allclose(rotation @ up_a, up_b)  # A's up still lands on B's
        assert np.allclose(rotation @ ca + h.T_b_from_a[:3, 3], cb)
        assert np.isclose(rotation_error_deg(rotation, composed[:3, :3]), min(45 * k, 360 - 45 * k))
