"""Relative poses, hypotheses, overlap scores, the choice and the pipeline (no model, no open3d)."""

import numpy as np
import pytest

from itnet.align import (
    Hypothesis,
    build_hypotheses,
    choose,
    confidence,
    nearest_distances,
    overlap_score,
    relative_pose,
    same_alignment,
    symmetry_rotations,
)
from itnet.alignment import AlignOptions, CloudEstimateError, PoseEstimate, align_clouds
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
    hyps = build_hypotheses([flip @ t_ca], [t_cb], symmetry_rotations("yaw180"), scale=1.0)
    assert [h.source for h in hyps] == ["itnet", "itnet+yaw180"]
    quarter = build_hypotheses([t_ca], [t_cb], symmetry_rotations("yaw90"), scale=1.0)
    assert [h.source for h in quarter] == ["itnet", *(f"itnet+yaw{a}" for a in (90, 180, 270))]
    assert rotation_error_deg(hyps[0].T_b_from_a[:3, :3], truth[:3, :3]) > 170
    assert np.allclose(hyps[1].T_b_from_a, truth, atol=1e-9)


def test_subset_hypotheses_skip_duplicates(rng):
    t_ca, t_cb = random_pose(rng, scale=0.5), random_pose(rng, scale=0.5)
    nudge = rigid_from_rotation_translation(axis_angle_to_matrix([1, 0, 0], np.radians(1)), 0)
    turn = rigid_from_rotation_translation(axis_angle_to_matrix([1, 0, 0], np.radians(40)), 0)
    poses_a = [t_ca, nudge @ t_ca, turn @ t_ca]  # sample 1 repeats the main estimate
    hyps = build_hypotheses(poses_a, [t_cb] * 3, symmetry_rotations("none"), scale=1.0)
    assert [h.source for h in hyps] == ["itnet", "sample 2"]


def test_same_alignment_thresholds():
    shifted = np.eye(4)
    shifted[0, 3] = 0.04
    assert same_alignment(np.eye(4), shifted, scale=1.0)
    assert not same_alignment(np.eye(4), shifted, scale=0.5)  # 0.04 > 0.05 x 0.5
    turned = rigid_from_rotation_translation(axis_angle_to_matrix([0, 0, 1], np.radians(6)), 0)
    assert not same_alignment(np.eye(4), turned, scale=1.0)


def test_nearest_distances_match_a_direct_search(rng):
    s, t = rng.normal(size=(70, 3)), rng.normal(size=(1500, 3))
    direct = np.array([np.linalg.norm(t - p, axis=1).min() for p in s])
    assert np.allclose(nearest_distances(s, t, chunk=16), direct, atol=1e-4)


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


def hyp(fitness, angle_deg=0.0):
    rot = axis_angle_to_matrix([0, 1, 0], np.radians(angle_deg))
    return Hypothesis(rigid_from_rotation_translation(rot, 0), "h", fitness, 0.01)


def test_choose_keeps_itnet_unless_clearly_beaten():
    assert choose([hyp(0.50), hyp(0.58, 180)], switch_margin=0.1) == 0
    assert choose([hyp(0.30), hyp(0.58, 180)], switch_margin=0.1) == 1
    assert choose([hyp(0.30), hyp(0.58, 180)], switch_margin=0.5) == 0


def test_confidence_falls_when_a_rival_fits_as_well():
    alone = confidence([hyp(0.8), hyp(0.1, 180)], 0, scale=1.0)
    tied = confidence([hyp(0.8), hyp(0.78, 180)], 0, scale=1.0)
    assert alone["confidence"] > 0.8 and tied["confidence"] < 0.5 * alone["confidence"]
    assert tied["margin"] == pytest.approx(0.02)
    # A hypothesis that agrees with the chosen one is no rival.
    assert confidence([hyp(0.8), hyp(0.8, 3)], 0, scale=1.0)["margin"] == pytest.approx(0.8)


def fake_estimator(clouds_and_poses, calls):
    def estimate(points):
        calls.append(len(points))
        for cloud, pose in clouds_and_poses:
            if points is cloud:
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


def test_align_clouds_without_icp_keeps_itnet_but_reports_the_better_rival(rng):
    a, b, truth, estimate, calls = flipped_pair(rng)
    result = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw180"))
    assert calls == [len(a), len(b)] and result.iterations == 8
    itnet, flipped = result.hypotheses
    assert result.chosen == 0 and itnet.source == "itnet"
    assert np.allclose(flipped.T_b_from_a, truth, atol=1e-9)
    assert flipped.fitness > 0.95 > 0.5 > itnet.fitness
    # A rival that fits better makes the margin negative: no confidence at all.
    assert result.confidence["margin"] < 0 and result.confidence["confidence"] == 0
    reply = result.to_dict()
    assert reply["hypothesis"] == "itnet" and np.allclose(reply["T_b_from_a"], itnet.T_b_from_a)
    assert reply["refined"] is False and reply["icp_distance"] == 0
    assert [h["source"] for h in reply["hypotheses"]] == ["itnet", "itnet+yaw180"]


def test_align_clouds_names_the_cloud_that_failed(rng):
    a = rng.normal(size=(50, 3))
    estimate = fake_estimator([(a, np.eye(4))], [])
    with pytest.raises(CloudEstimateError, match="cloud B: 3 points is too few") as info:
        align_clouds(a, rng.normal(size=(3, 3)), estimate, AlignOptions())
    assert info.value.cloud == "B" and isinstance(info.value.__cause__, ValueError)


def test_align_clouds_runs_subsets(rng):
    calls: list[int] = []

    def estimate(points):
        calls.append(len(points))
        return PoseEstimate(np.eye(4), 1, 0.1, "budget")

    a, b = rng.normal(size=(100, 3)), rng.normal(size=(50, 3))
    result = align_clouds(a, b, estimate, AlignOptions(samples=3, symmetry="none"))
    assert calls == [100, 80, 80, 50, 40, 40]
    assert len(result.hypotheses) == 1  # the subset estimates agree: no new hypothesis
    assert result.iterations == 6
