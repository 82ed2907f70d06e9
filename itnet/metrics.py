"""Pose and alignment errors as SPEC.md defines them (pure numpy).

A pose is correct when its rotation error is below 10 degrees AND its translation error below
0.1 object radii.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import FloatArray, invert_rigid, rotation_error_deg

ROTATION_THRESHOLD_DEG = 10.0
TRANSLATION_THRESHOLD = 0.1


def pose_errors(
    estimate: ArrayLike, truth: ArrayLike, radius: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """T_canonical_from_input estimates and truths (...x4x4), object radius (...) ->
    (rotation error in degrees (...), object-centre distance in the input frame / radius (...)).

    The object centre in the input frame is the translation of inv(T_canonical_from_input).
    """
    est, gt = np.asarray(estimate), np.asarray(truth)
    rot = rotation_error_deg(est[..., :3, :3], gt[..., :3, :3])
    centre_est = invert_rigid(est)[..., :3, 3]
    centre_gt = invert_rigid(gt)[..., :3, 3]
    return rot, np.linalg.norm(centre_est - centre_gt, axis=-1) / np.asarray(radius)


def alignment_errors(
    estimate: ArrayLike, truth: ArrayLike, centroid_a: ArrayLike, radius: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """T_b_from_a estimates and truths (...x4x4), centroid of cloud A (...x3), radius (...) ->
    (rotation error in degrees, distance between where the two put A's centroid / radius)."""
    est, gt = np.asarray(estimate), np.asarray(truth)
    c = np.asarray(centroid_a)
    rot = rotation_error_deg(est[..., :3, :3], gt[..., :3, :3])
    moved_est = np.einsum("...ij,...j->...i", est[..., :3, :3], c) + est[..., :3, 3]
    moved_gt = np.einsum("...ij,...j->...i", gt[..., :3, :3], c) + gt[..., :3, 3]
    return rot, np.linalg.norm(moved_est - moved_gt, axis=-1) / np.asarray(radius)


def is_correct(
    rotation_error_deg: ArrayLike,
    translation_error: ArrayLike,
    max_rotation_deg: float = ROTATION_THRESHOLD_DEG,
    max_translation: float = TRANSLATION_THRESHOLD,
) -> NDArray[np.bool_]:
    """The paper's success test, elementwise."""
    return (np.asarray(rotation_error_deg) < max_rotation_deg) & (
        np.asarray(translation_error) < max_translation
    )


def paired_accuracy(correct: ArrayLike, baseline: ArrayLike) -> dict[str, float]:
    """Right or wrong per scan (S,) of a method and of a baseline on the same scans -> its
    accuracy with the binomial standard error, and its paired gain over the baseline with the
    standard error of the per-scan differences; in percent, to 0.1, and the scan count."""
    ok, base = np.asarray(correct, np.float64), np.asarray(baseline, np.float64)
    acc, diff = float(ok.mean()), ok - base
    return {
        "accuracy": round(100 * acc, 1),
        "stderr": round(100 * float(np.sqrt(acc * (1 - acc) / len(ok))), 1),
        "gain": round(100 * float(diff.mean()), 1),
        "gain_stderr": round(100 * float(diff.std() / np.sqrt(len(ok))), 1),
        "scans": len(ok),
    }
