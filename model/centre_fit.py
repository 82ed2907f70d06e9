"""Fit a pose model's centre correction (``itnet.centre``) and measure it on validation views.

Scans of the category's *training* shapes (occluded and paper views, their own seed) are posed
by the model as the service serves them (``AnytimeRun``, the card's mirror finish, no centre
correction); each final pose gives the features of the moved cloud and where the true object
centre lies in that frame. A ridge regression on the scans whose rotation is within 20 degrees
(the others are in a wrong basin, where no centre helps) is the correction. It is then measured
on the validation views (held-out training shapes, as ``itnet train`` validates), one run, with
and without it: the correction moves only the translation, so both come from the same runs.
The scanner's camera sits at the origin of each scan's frame, so the same scans also fit the
viewpoint correction (the sensor's direction as three more features).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from itnet.centre import (
    CentreCorrection,
    centre_features,
    fit_centre_correction,
    sensor_direction,
)
from itnet.geometry import apply_rigid
from itnet.metrics import is_correct, paired_accuracy
from itnet.model.data import ScanSet
from itnet.model.evaluate import report
from itnet.pose.loop import AnytimeRun
from itnet.pose.plan import plan
from itnet.pose.request import PoseRequest
from itnet.pose.runtime import LoadedModel

FIT_MAX_ROTATION_DEG = 20.0


@dataclass
class ServedCentres:
    """Per scan (S): features (S, F) of the moved cloud, the true centre's offset (S, 3) in the
    moved, normalised frame, the normalised scale over the object radius (S,), the served
    pose's rotation and translation errors (S,) (degrees, object radii), and the direction
    toward the camera (S, 3) in the moved frame."""

    features: NDArray[np.float64]
    offsets: NDArray[np.float64]
    scale_over_radius: NDArray[np.float64]
    rotation_deg: NDArray[np.float64]
    translation: NDArray[np.float64]
    toward: NDArray[np.float64]

    def with_viewpoint(self) -> NDArray[np.float64]:
        """The viewpoint correction's features (S, F + 3)."""
        return np.concatenate([self.features, self.toward], axis=1)


def served_centres(
    model: LoadedModel,
    scans: ScanSet,
    symmetry: str,
    ensemble: int = 1,
    ups: NDArray[np.float64] | None = None,
) -> ServedCentres:
    """Pose every scan as served (``ensemble`` runs fused, no centre correction; ``ups`` (S, 3):
    each scan's up direction as the caller gives it, the runs then held upright) and measure
    its centre."""
    features, offsets, ratio, poses, toward = [], [], [], [], []
    given = [None] * len(scans.clouds) if ups is None else list(ups)
    for cloud, truth, radius, up in zip(scans.clouds, scans.poses, scans.radii, given):
        up_list = None if up is None else [float(v) for v in up]
        request = PoseRequest(budget_ms=1000.0, ensemble=ensemble, centre=False, up=up_list)
        run = AnytimeRun(plan(model, request), cloud)
        last = run.run_to_end()
        pose_n = last.pose_normalized.astype(np.float64)
        moved = apply_rigid(pose_n, run.points[0].astype(np.float64))
        norm = run.normalization
        centre = -truth[:3, :3].T @ truth[:3, 3]  # the object's centre in the input frame
        offsets.append(apply_rigid(pose_n, ((centre - norm.center) / norm.scale)[None])[0])
        features.append(centre_features(moved))
        ratio.append(norm.scale / float(radius))
        poses.append(last.pose)
        toward.append(sensor_direction(pose_n, -norm.center / norm.scale))  # camera at the origin
    _, rot, trans = report(np.stack(poses)[:, None], scans, symmetry)
    return ServedCentres(
        np.array(features), np.array(offsets), np.array(ratio), rot[:, -1], trans[:, -1],
        np.array(toward),
    )  # fmt: skip


def fit(
    served: list[ServedCentres],
    ridge: float = 10.0,
    max_rotation_deg: float = FIT_MAX_ROTATION_DEG,
    viewpoint: bool = False,
) -> CentreCorrection:
    """The correction from served training scans, fitted where the rotation is within
    ``max_rotation_deg`` (``viewpoint``: the sensor's direction as well). Raises ValueError when
    fewer than 10 scans are."""
    keep = [s.rotation_deg < max_rotation_deg for s in served]
    if sum(int(k.sum()) for k in keep) < 10:
        raise ValueError(
            f"only {sum(int(k.sum()) for k in keep)} training scans were posed within "
            f"{max_rotation_deg:g} degrees: the model is not accurate enough to fit a centre "
            "correction on"
        )
    return fit_centre_correction(
        np.concatenate(
            [(s.with_viewpoint() if viewpoint else s.features)[k] for s, k in zip(served, keep)]
        ),
        np.concatenate([s.offsets[k] for s, k in zip(served, keep)]),
        ridge,
    )


def measure(served: ServedCentres, correction: CentreCorrection) -> dict[str, float]:
    """Accuracy at (10 deg, 0.1 r) without and with the correction on the same runs (paired),
    and the median translation error of the scans whose rotation is right, before and after."""
    features = served.with_viewpoint() if correction.uses_viewpoint else served.features
    predicted = correction.predict(features)
    after = np.linalg.norm(served.offsets - predicted, axis=1) * served.scale_over_radius
    before = served.translation
    right = served.rotation_deg < 10
    without = is_correct(served.rotation_deg, before).astype(float)
    with_ = is_correct(served.rotation_deg, after).astype(float)
    return {
        "without": round(100 * float(without.mean()), 1),
        **paired_accuracy(with_, without),
        "median_translation_without": _median(before[right]),
        "median_translation_with": _median(after[right]),
    }


def _median(values: NDArray) -> float | None:
    return round(float(np.median(values)), 4) if len(values) else None


def describe(
    results: dict[str, dict[str, float]], what: str = "the centre correction", runs: str = "one run"
) -> str:
    """The card's ``centre_evaluation`` line from ``measure``'s results by view kind."""

    def median(value: float | None) -> str:
        return "n/a" if value is None else f"{value:.3f}"

    parts = [
        f"{kind} {r['without']:.1f}% -> {r['accuracy']:.1f}% ({r['gain']:+.1f} +- "
        f"{r['gain_stderr']:.1f}, {r['scans']} scans; median centre error where the rotation "
        f"is right {median(r['median_translation_without'])} -> "
        f"{median(r['median_translation_with'])} r)"
        for kind, r in results.items()
    ]
    return f"validation views, {runs}, without and with {what}: " + "; ".join(parts)
