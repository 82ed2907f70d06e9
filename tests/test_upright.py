"""Poses held upright (itnet.upright) and the engine's ``up``: the pose takes the given up
direction onto the canonical +y, the object's centre stays, and bad or conflicting input is
refused."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from itnet.geometry import apply_rigid, invert_rigid, random_rotation
from itnet.pose.errors import BadCloudError
from itnet.upright import (
    UP,
    held_upright,
    levelled,
    rotation_onto,
    sensed_ups,
    tilted,
    unit_up,
    upright_starts,
)
from tests.pose_runs import run_with


def test_rotation_onto_takes_one_direction_onto_another(rng) -> None:
    a = rng.normal(size=(50, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = rng.normal(size=(50, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    r = rotation_onto(a, b)
    np.testing.assert_allclose(np.einsum("sij,sj->si", r, a), b, atol=1e-9)
    np.testing.assert_allclose(
        r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape), atol=1e-9
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-9)
    # the least rotation: its angle is the angle between the two
    angle = np.degrees(np.arccos(np.clip((np.trace(r, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    np.testing.assert_allclose(angle, np.degrees(np.arccos(np.sum(a * b, axis=1))), atol=1e-6)


@pytest.mark.parametrize("a", [UP, -UP, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])])
def test_rotation_onto_handles_parallel_and_opposite_directions(a) -> None:
    r = rotation_onto(a, UP)
    np.testing.assert_allclose(r @ a, UP, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-9)


def test_held_upright_takes_up_onto_y_and_keeps_the_centre(rng) -> None:
    up = unit_up(rng.normal(size=3))
    poses = np.tile(np.eye(4), (20, 1, 1))
    poses[:, :3, :3] = random_rotation(rng, 20)
    poses[:, :3, 3] = rng.normal(size=(20, 3))
    held = held_upright(poses, up)
    np.testing.assert_allclose(held[:, :3, :3] @ up, np.tile(UP, (20, 1)), atol=1e-9)
    centres = invert_rigid(poses)[:, :3, 3]  # where each pose puts the canonical origin
    np.testing.assert_allclose(invert_rigid(held)[:, :3, 3], centres, atol=1e-9)
    np.testing.assert_allclose(held_upright(held, up), held, atol=1e-9)  # already upright


def test_held_upright_stays_rigid_for_float32_rotations_in_any_direction(rng) -> None:
    """A network's rotations are orthonormal only to float32 rounding, and a run may leave up
    anywhere, next to upside down too: the turn that stands it up is still a rotation, the
    general one within rounding, and takes up onto +y."""
    up = unit_up([0.2, -1.0, 0.1])
    poses = np.tile(np.eye(4), (400, 1, 1))
    poses[:, :3, :3] = random_rotation(rng, 400).astype(np.float32)
    lift = rotation_onto(up, -UP)  # the rotation that puts up exactly onto -y, with neighbours
    poses[:4, :3, :3] = np.stack([np.eye(3), rotation_onto(UP, [1e-4, 1.0, 0.0])] * 2) @ lift
    held = held_upright(poses, up)
    rotations = held[:, :3, :3]
    np.testing.assert_allclose(rotations @ np.swapaxes(rotations, 1, 2),
                               np.tile(np.eye(3), (400, 1, 1)), atol=1e-6)  # fmt: skip
    np.testing.assert_allclose(rotations @ up, np.tile(UP, (400, 1)), atol=1e-6)
    lifted = poses[:, :3, :3].astype(np.float64) @ up
    general = rotation_onto(lifted / np.linalg.norm(lifted, axis=1, keepdims=True), UP)
    np.testing.assert_allclose(rotations, general @ poses[:, :3, :3], atol=1e-12)


def test_upright_starts_stand_the_cloud_up_at_turns_about_y(rng) -> None:
    up = unit_up([0.3, -1.0, 0.2])
    starts = upright_starts(up, 4)
    np.testing.assert_allclose(starts @ up, np.tile(UP, (4, 1)), atol=1e-9)
    # consecutive starts differ by a quarter turn about +y
    turn = starts[1] @ starts[0].T
    np.testing.assert_allclose(turn @ UP, UP, atol=1e-9)
    np.testing.assert_allclose(np.degrees(np.arccos((np.trace(turn) - 1) / 2)), 90.0, atol=1e-6)


@pytest.mark.parametrize("bad", [[0, 0, 0], [1, 2], [np.nan, 1, 0], [np.inf, 0, 0]])
def test_unit_up_refuses_what_is_not_a_direction(bad) -> None:
    with pytest.raises(ValueError, match="up"):
        unit_up(bad)


@pytest.mark.parametrize("ensemble", [1, 4])
def test_engine_holds_every_estimate_upright(model, rng, ensemble) -> None:
    cloud = rng.normal(size=(400, 3)) * [0.3, 0.2, 0.1] + [1.0, 2.0, 3.0]
    up = [0.2, -0.9, 0.1]  # a camera whose image y points down, tilted
    run = run_with(model, cloud, budget_ms=10_000, max_iterations=5, ensemble=ensemble, up=up)
    estimates = list(run)
    assert len(estimates) == 5
    for e in estimates:
        np.testing.assert_allclose(e.pose[:3, :3] @ unit_up(up), UP, atol=1e-4)
    result = run.result()
    np.testing.assert_allclose(result["up"], unit_up(up), atol=1e-6)
    final = np.asarray(result["T_canonical_from_input"])
    np.testing.assert_allclose(final[:3, :3] @ unit_up(up), UP, atol=1e-4)
    # without up the tiny network's poses tilt freely
    free = run_with(model, cloud, budget_ms=10_000, max_iterations=5, ensemble=ensemble)
    tilt = free.run_to_end().pose[:3, :3] @ unit_up(up)
    assert np.degrees(np.arccos(np.clip(tilt @ UP, -1, 1))) > 1.0
    assert "up" not in free.result()


def test_engine_refuses_bad_or_conflicting_up(model, rng) -> None:
    cloud = rng.normal(size=(300, 3))
    with pytest.raises(BadCloudError, match="zero"):
        run_with(model, cloud, up=[0, 0, 0])
    with pytest.raises(BadCloudError, match="three finite"):
        run_with(model, cloud, up=[0, np.inf, 1])
    with pytest.raises(ValueError, match="up"):
        run_with(model, cloud, up=[0, 1])


def test_upright_starts_stand_up_and_turn_about_up(rng) -> None:
    up = unit_up([0.3, -1.0, 0.2])
    starts = upright_starts(up, 4)
    np.testing.assert_allclose(starts[0], rotation_onto(up, UP), atol=1e-9)
    np.testing.assert_allclose(starts @ up, np.tile(UP, (4, 1)), atol=1e-9)
    turns = starts @ starts[0].T  # each start after the first's: a turn about +y
    np.testing.assert_allclose(turns @ UP, np.tile(UP, (4, 1)), atol=1e-9)
    np.testing.assert_allclose(np.degrees(np.arccos(np.clip(turns[1:, 0, 0], -1, 1))),
                               [90.0, 180.0, 90.0], atol=1e-6)  # fmt: skip


def test_tilted_ups_are_off_by_the_error_and_levelled_clouds_stand(rng) -> None:
    ups = rng.normal(size=(30, 3))
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    off = tilted(ups, 2.0, rng)
    np.testing.assert_allclose(np.linalg.norm(off, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.degrees(np.arccos(np.sum(ups * off, axis=1))), 2.0, atol=1e-6)
    poses = np.tile(np.eye(4), (30, 1, 1))
    poses[:, :3, :3] = random_rotation(rng, 30)
    truth = np.einsum("sji,j->si", poses[:, :3, :3], UP)  # R^T e_y: +y in each scan's frame
    np.testing.assert_allclose(sensed_ups(poses, 0.0, rng), truth, atol=1e-12)
    sensed = sensed_ups(poses, 2.0, rng)
    np.testing.assert_allclose(
        np.degrees(np.arccos(np.sum(truth * sensed, axis=1))), 2.0, atol=1e-6
    )
    cloud = rng.normal(size=(50, 3))
    flat = levelled(cloud, ups[0])
    np.testing.assert_allclose(levelled(ups[0][None], ups[0])[0], UP, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(flat, axis=1), np.linalg.norm(cloud, axis=1))


def test_fused_runs_with_up_start_turned_about_it_and_stay_upright(model, rng) -> None:
    """Fused runs given up start stood up, yaw turns apart, and every run stays upright."""
    cloud = rng.normal(size=(400, 3)) * [0.3, 0.2, 0.1]
    up = unit_up([0.2, -0.9, 0.1])
    run = run_with(model, cloud, budget_ms=10_000, max_iterations=3, ensemble=3, up=up)
    np.testing.assert_allclose(run.pose_normalized[:, :3, :3], upright_starts(up, 3), atol=1e-6)
    run.run_to_end()
    poses = run.poses()
    np.testing.assert_allclose(poses[:, :3, :3] @ up, np.tile(UP, (3, 1)), atol=1e-4)
    np.testing.assert_allclose(run.last.pose[:3, :3] @ up, UP, atol=1e-4)


def test_a_model_that_requires_up_refuses_a_request_without_it(model, rng) -> None:
    needs = copy.copy(model)
    needs.card = model.card.model_copy(update={"requires_up": True})
    cloud = rng.normal(size=(300, 3))
    with pytest.raises(BadCloudError, match="needs 'up'"):
        run_with(needs, cloud)
    run = run_with(needs, cloud, up=[0, 0, 1], budget_ms=10_000, max_iterations=3)
    pose = run.run_to_end().pose
    np.testing.assert_allclose(pose[:3, :3] @ [0, 0, 1], UP, atol=1e-4)
    assert np.isfinite(apply_rigid(pose, cloud)).all()


def test_free_steps_run_unheld_and_the_final_pose_is_still_upright(model, rng) -> None:
    free = copy.copy(model)
    free.card = model.card.model_copy(update={"up_free_steps": 2})
    cloud = rng.normal(size=(400, 3)) * [0.3, 0.2, 0.1]
    up = unit_up([0.3, 1.0, -0.2])

    def tilt(pose: np.ndarray) -> float:
        return float(np.degrees(np.arccos(np.clip((pose[:3, :3] @ up) @ UP, -1, 1))))

    run = run_with(free, cloud, budget_ms=10_000, max_iterations=4, up=up, mirror=False)
    estimates = list(run)
    assert tilt(estimates[0].pose) > 1.0 and tilt(estimates[1].pose) > 1.0  # free
    assert tilt(estimates[2].pose) < 1e-2 and tilt(estimates[3].pose) < 1e-2  # held
    # a run that stops within the free steps is stood up at the end
    short = run_with(free, cloud, budget_ms=10_000, max_iterations=1, up=up, mirror=False)
    (only,) = list(short)
    assert tilt(only.pose) > 1.0  # the step itself ran free
    assert tilt(short.run_to_end().pose) < 1e-2  # and the finish stood it up
    assert tilt(np.asarray(short.result()["T_canonical_from_input"])) < 1e-2


@pytest.mark.parametrize("free_steps", [0, 2])
def test_the_evaluation_holds_each_run_upright_as_the_service_does(model, rng, free_steps) -> None:
    """``itnet eval --up``: each scan's run stood up (after the free steps) by its given up, the
    same poses as the engine's single run with that up."""
    from itnet.model.data import ScanSet
    from itnet.model.evaluate import anytime_poses

    clouds = [rng.normal(size=(256, 3)) * [0.3, 0.2, 0.1] + rng.normal(size=3) for _ in range(3)]
    ups = np.stack([unit_up(rng.normal(size=3)) for _ in clouds])
    scans = ScanSet(clouds, np.tile(np.eye(4), (3, 1, 1)), np.ones(3), ["a", "b", "c"])
    step = lambda x, p: model.step(x, p)[0]  # noqa: E731
    poses = anytime_poses(step, scans, 4, 256, batch=1, ups=ups, free_steps=free_steps)
    for s, up in enumerate(ups):
        tilt = np.degrees(np.arccos(np.clip(poses[s, :, :3, :3] @ up @ UP, -1, 1)))
        assert (tilt[max(1, free_steps + 1) :] < 0.05).all()  # float32 poses
        if free_steps:
            assert tilt[1] > 1.0  # the free steps ran unheld
    free = copy.copy(model)
    free.card = model.card.model_copy(update={"up_free_steps": free_steps})
    run = run_with(free, clouds[0], budget_ms=10_000, max_iterations=4, up=ups[0],
                     mirror=False, centre=False)  # fmt: skip
    served = [e.pose for e in run]
    np.testing.assert_allclose(poses[0, 1:], np.stack(served), atol=1e-3)
