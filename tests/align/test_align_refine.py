"""ICP refinement (open3d) on synthetic shapes moved by known transforms."""

import numpy as np
import pytest

from itnet.geometry import (
    apply_rigid,
    axis_angle_to_matrix,
    invert_rigid,
    random_rotation,
    rigid_from_rotation_translation,
    rotation_error_deg,
)

o3d = pytest.importorskip("open3d")

from itnet.alignment.hypotheses import symmetry_rotations  # noqa: E402
from itnet.alignment.pipeline import AlignOptions, PoseEstimate, align_clouds  # noqa: E402
from itnet.alignment.refine import IcpRefiner, icp_point_to_plane  # noqa: E402


def sampled(mesh, count: int, seed: int) -> np.ndarray:
    o3d.utility.random.seed(seed)
    return np.asarray(mesh.sample_points_uniformly(count).points)


def small_motion(deg: float, shift: list[float], axis=(0.3, 1.0, -0.2)) -> np.ndarray:
    rot = axis_angle_to_matrix(axis, np.radians(deg))
    return rigid_from_rotation_translation(rot, shift)


def torus():
    return o3d.geometry.TriangleMesh.create_torus(torus_radius=1.0, tube_radius=0.3)


def box():
    return o3d.geometry.TriangleMesh.create_box(1.0, 0.6, 0.3)


# The torus turns about an axis in its plane: a turn about its own axis (z) is invisible.
@pytest.mark.parametrize(
    ("make", "axis"), [(torus, (1.0, 0.4, 0.0)), (box, (0.3, 1.0, -0.2))], ids=["torus", "box"]
)
def test_icp_recovers_a_known_small_motion(make, axis):
    mesh = make()
    a = sampled(mesh, 1500, seed=1)
    b_from_a = small_motion(8.0, [0.06, -0.04, 0.03], axis)
    b = apply_rigid(b_from_a, sampled(mesh, 1500, seed=2))  # other samples of the same surface
    result = icp_point_to_plane(a, b, np.eye(4), max_distance=0.1)
    assert rotation_error_deg(result.T_b_from_a[:3, :3], b_from_a[:3, :3]) < 0.5
    assert np.linalg.norm(result.T_b_from_a[:3, 3] - b_from_a[:3, 3]) < 0.01
    assert result.fitness > 0.95 and result.rmse < 0.05


def test_icp_on_a_partial_view_keeps_a_right_start():
    # B sees only part of the box: a correct start must stay put (the Tukey kernel and the
    # correspondence cut-off stop A's unseen part from dragging it).
    a = sampled(box(), 2000, seed=3)
    part = sampled(box(), 2000, seed=4)
    part = part[(part[:, 0] > 0.4) & (part[:, 2] > 0.1)]
    b_from_a = small_motion(40.0, [1.0, 2.0, 3.0])
    b = apply_rigid(b_from_a, part)
    refiner = IcpRefiner(a, b, max_distance=0.05)
    result = refiner.refine(b_from_a)
    assert rotation_error_deg(result.T_b_from_a[:3, :3], b_from_a[:3, :3]) < 1.0
    assert np.linalg.norm(result.T_b_from_a[:3, 3] - b_from_a[:3, 3]) < 0.02
    # ... and a start 5 degrees off (about A's centre) comes back, with the same prepared clouds.
    centre = a.mean(axis=0)
    turn = small_motion(5.0, [0.0, 0.0, 0.0], (1.0, 0.0, 0.5))
    turn[:3, 3] = centre - turn[:3, :3] @ centre
    nudged = b_from_a @ turn
    again = refiner.refine(nudged)
    assert rotation_error_deg(again.T_b_from_a[:3, :3], b_from_a[:3, :3]) < 1.0
    assert np.allclose(invert_rigid(again.T_b_from_a) @ b_from_a, np.eye(4), atol=0.03)


def test_bad_distance_is_refused():
    with pytest.raises(ValueError, match="max_distance"):
        IcpRefiner(np.zeros((10, 3)), np.zeros((10, 3)), max_distance=0.0)


def _misread_lopsided_object(rng):
    """A lopsided object (a slab and a post on one corner) seen in two frames, the true
    T_b_from_a, and an estimator that reads A turned 180 degrees about up, 4 degrees off."""
    obj = np.concatenate([rng.uniform([-1, -0.1, -0.6], [1, 0.1, 0.6], size=(300, 3)),
                          rng.uniform([0.6, 0.1, -0.6], [1, 1.2, -0.3], size=(300, 3))])  # fmt: skip
    t_ca = rigid_from_rotation_translation(random_rotation(rng), [0.3, -0.2, 2.5])
    t_cb = rigid_from_rotation_translation(random_rotation(rng), [-0.4, 0.1, 3.0])
    a, b = apply_rigid(invert_rigid(t_ca), obj), apply_rigid(invert_rigid(t_cb), obj)
    misread = symmetry_rotations("yaw180")[0] @ small_motion(4.0, [0, 0, 0]) @ t_ca

    def estimate(points, up=None):
        pose = misread if (a == points[0]).all(axis=1).any() else t_cb
        return PoseEstimate(pose, 3, 1.0, "max_iterations")

    return a, b, invert_rigid(t_cb) @ t_ca, estimate


def test_align_clouds_with_icp_switches_to_the_symmetric_hypothesis(rng):
    a, b, truth, estimate = _misread_lopsided_object(rng)
    result = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw180", refine=True))
    assert result.hypotheses[result.chosen].source == "itnet+yaw180+icp"
    assert rotation_error_deg(result.T_b_from_a[:3, :3], truth[:3, :3]) < 1.0
    assert result.hypotheses[result.chosen].fitness > 0.9 and result.probability > 0.9
    assert result.runner_up().probability < result.probability  # type: ignore[union-attr]
    # Without the symmetry hypotheses, ICP alone cannot undo a half turn, and says so.
    plain = align_clouds(a, b, estimate, AlignOptions(symmetry="none", refine=True))
    assert rotation_error_deg(plain.T_b_from_a[:3, :3], truth[:3, :3]) > 90
    assert plain.probability < 0.9 and plain.probability < result.probability  # in doubt


def test_only_the_finalists_get_the_fine_stage(rng, monkeypatch):
    a, b, truth, estimate = _misread_lopsided_object(rng)
    stages: list[slice] = []
    original = IcpRefiner.refine

    def spy(self, b_from_a, stages_=slice(None)):
        stages.append(stages_)
        return original(self, b_from_a, stages_)

    monkeypatch.setattr(IcpRefiner, "refine", spy)
    options = AlignOptions(symmetry="yaw90", refine=True, candidates=4, finalists=1)
    result = align_clouds(a, b, estimate, options)
    # the composed pose as it is and refined, then its three turns (the only rivals there are)
    assert len(result.hypotheses) == 5 and all(h.icp is not None for h in result.hypotheses[1:])
    # the composed pose's coarse and fine stages; the rivals' coarse, the best one's fine
    assert stages == [slice(1), slice(1, None)] + [slice(1)] * 3 + [slice(1, None)]
    assert result.hypotheses[result.chosen].source == "itnet+yaw180+icp"
    assert rotation_error_deg(result.T_b_from_a[:3, :3], truth[:3, :3]) < 1.0


def test_dense_clouds_in_millimetres_align(rng):
    """30,000 points a cloud, in mm: the scoring trees take a subset, ICP a voxel grid, and the
    answer is the same as for the sparse clouds."""
    obj = (
        np.concatenate(
            [
                rng.uniform([-1, -0.1, -0.6], [1, 0.1, 0.6], size=(15_000, 3)),
                rng.uniform([0.6, 0.1, -0.6], [1, 1.2, -0.3], size=(15_000, 3)),
            ]
        )
        * 1000
    )
    t_ca = rigid_from_rotation_translation(random_rotation(rng), [300.0, -200.0, 2500.0])
    t_cb = rigid_from_rotation_translation(random_rotation(rng), [-400.0, 100.0, 3000.0])
    a, b = apply_rigid(invert_rigid(t_ca), obj), apply_rigid(invert_rigid(t_cb), obj[::-1])
    misread = symmetry_rotations("yaw180")[0] @ small_motion(4.0, [0, 0, 0]) @ t_ca

    def estimate(points, up=None):
        pose = misread if points is a else t_cb
        return PoseEstimate(pose, 3, 1.0, "max_iterations")

    result = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw180", refine=True))
    truth = invert_rigid(t_cb) @ t_ca
    assert rotation_error_deg(result.T_b_from_a[:3, :3], truth[:3, :3]) < 1.0
    assert np.linalg.norm(result.T_b_from_a[:3, 3] - truth[:3, 3]) < 10.0  # mm
    assert result.hypotheses[result.chosen].fitness > 0.8


def test_the_coarse_stage_can_run_on_a_subset_of_a():
    mesh = box()
    a = sampled(mesh, 1500, seed=1)
    b_from_a = small_motion(8.0, [0.06, -0.04, 0.03])
    b = apply_rigid(b_from_a, sampled(mesh, 1500, seed=2))
    refiner = IcpRefiner(a, b, max_distance=0.1, coarse_points=100)
    assert len(refiner.coarse_source.points) == 100 and len(refiner.source.points) == 1500
    coarse = refiner.refine(np.eye(4), slice(1))
    assert rotation_error_deg(coarse.T_b_from_a[:3, :3], b_from_a[:3, :3]) < 3.0
    fine = refiner.refine(coarse.T_b_from_a, slice(1, None))
    assert rotation_error_deg(fine.T_b_from_a[:3, :3], b_from_a[:3, :3]) < 0.5
    assert len(IcpRefiner(a, b, 0.1, coarse_points=5000).coarse_source.points) == 1500


def test_known_ups_let_a_yaw_sweep_undo_a_turn_no_symmetry_explains(rng):
    # A's pose read 70 degrees off about up: neither a symmetry turn nor ICP from the composed
    # pose reaches the truth; with both clouds' ups given, one of the turns about up does.
    obj = np.concatenate([rng.uniform([-1, -0.1, -0.6], [1, 0.1, 0.6], size=(300, 3)),
                          rng.uniform([0.6, 0.1, -0.6], [1, 1.2, -0.3], size=(300, 3))])  # fmt: skip
    t_ca = rigid_from_rotation_translation(random_rotation(rng), [0.3, -0.2, 2.5])
    t_cb = rigid_from_rotation_translation(random_rotation(rng), [-0.4, 0.1, 3.0])
    a, b = apply_rigid(invert_rigid(t_ca), obj), apply_rigid(invert_rigid(t_cb), obj)
    truth = invert_rigid(t_cb) @ t_ca
    misread = rigid_from_rotation_translation(axis_angle_to_matrix([0, 1, 0], np.radians(70.0)),
                                              [0.0, 0.0, 0.0]) @ t_ca  # fmt: skip

    def estimate(points, up=None):
        pose = misread if (a == points[0]).all(axis=1).any() else t_cb
        return PoseEstimate(pose, 3, 1.0, "max_iterations")

    ups = (t_ca[:3, :3].T @ [0, 1, 0], t_cb[:3, :3].T @ [0, 1, 0])  # canonical +y in each
    options = AlignOptions(symmetry="yaw180", refine=True)
    swept = align_clouds(a, b, estimate, options, *ups)
    assert swept.hypotheses[swept.chosen].source.startswith("sweep yaw")
    assert rotation_error_deg(swept.T_b_from_a[:3, :3], truth[:3, :3]) < 2.0
    plain = align_clouds(a, b, estimate, AlignOptions(symmetry="yaw180", refine=True, sweep=0),
                         *ups)  # fmt: skip
    assert rotation_error_deg(plain.T_b_from_a[:3, :3], truth[:3, :3]) > 30
    assert not any(h.source.startswith("sweep") for h in plain.hypotheses)
    free = align_clouds(a, b, estimate, options)  # no ups: no sweep
    assert not any(h.source.startswith("sweep") for h in free.hypotheses)


def test_a_refine_past_its_deadline_stops_after_the_first_coarse_stage(rng):
    from itnet.alignment.hypotheses import Hypothesis
    from itnet.alignment.pipeline import _Judge

    a, b, truth, _ = _misread_lopsided_object(rng)
    judge = _Judge(a, b, truth[None], AlignOptions(refine=True))
    starts = [Hypothesis(truth @ small_motion(d, [0, 0, 0]), f"h{d}") for d in (3.0, 6.0, 9.0)]
    fine = judge.refine(starts, finalists=1, deadline=0.0)  # long past
    assert fine == [0] and starts[0].initial is not None
    assert all(h.initial is None and h.icp is None for h in starts[1:])
    assert judge.refine(starts[1:], finalists=1) in ([0], [1])  # no deadline: both refined
    assert all(h.initial is not None for h in starts)
