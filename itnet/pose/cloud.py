"""Checking what a request sends: the cloud (N, 3) and its directions, against stated limits;
and the cloud a request poses, a cut-out's floor and walls taken away.

Every check raises ``BadCloudError`` with a sentence that says what is wrong; nothing here
depends on a model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.floor_and_walls import Stripped, strip_floor_and_walls
from itnet.pose.errors import BadCloudError
from itnet.pose.request import PoseRequest
from itnet.preprocess import DegenerateCloudError, Normalization, estimate_normalization
from itnet.size_prior import metres_per_unit
from itnet.upright import unit_up

# Larger coordinates overflow the normalisation's squares (1e200 ** 2 is inf in float64) and
# would be called degenerate; 1e12 leaves float64 room for any physical unit.
MAX_COORDINATE = 1e12


@dataclass(frozen=True)
class Limits:
    """What one request may ask for (the service's settings set them; see docs/hardening.md)."""

    min_points: int = 32
    max_points: int = 1_000_000
    max_budget_ms: float = 60_000.0
    max_iterations: int = 200


def validate_cloud(points: ArrayLike, limits: Limits) -> NDArray[np.float64]:
    """Any array-like -> (N, 3) float64, or BadCloudError saying what is wrong."""
    try:
        cloud = np.asarray(points, dtype=np.float64)
    except (ValueError, TypeError) as err:
        raise BadCloudError(f"points must be a list of [x, y, z] numbers ({err})") from None
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise BadCloudError(f"points must have shape (N, 3), got {cloud.shape}")
    if not np.isfinite(cloud).all():
        bad = int((~np.isfinite(cloud)).any(axis=1).sum())
        raise BadCloudError(f"{bad} point(s) have NaN or infinite coordinates")
    if len(cloud) < limits.min_points:
        raise BadCloudError(f"{len(cloud)} points is too few (the minimum is {limits.min_points})")
    if len(cloud) > limits.max_points:
        raise BadCloudError(f"{len(cloud)} points is too many (the maximum is {limits.max_points})")
    if np.abs(cloud).max(initial=0.0) > MAX_COORDINATE:
        raise BadCloudError(
            f"coordinates out of range: |x|, |y|, |z| must be at most {MAX_COORDINATE:g} "
            f"(got {np.abs(cloud).max():.3g}); send the cloud in a smaller unit"
        )
    return cloud


def normalization_of(cloud: NDArray[np.float64]) -> Normalization:
    """The cloud's normalisation (``itnet.preprocess``), or BadCloudError for a degenerate one."""
    try:
        return estimate_normalization(cloud)
    except DegenerateCloudError as err:
        raise BadCloudError(str(err)) from None


def validate_viewpoint(viewpoint: ArrayLike) -> NDArray[np.float64]:
    """The sensor's position (3,), finite, or BadCloudError."""
    try:
        point = np.asarray(viewpoint, dtype=np.float64)
    except (TypeError, ValueError):
        point = np.empty(0)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise BadCloudError("viewpoint must be three finite numbers: the sensor's x, y, z")
    return point


def validate_up(up: ArrayLike) -> NDArray[np.float64]:
    """A request's up direction -> its unit vector (3,); BadCloudError saying what is wrong
    (not three finite numbers, or zero)."""
    try:
        return np.asarray(unit_up(np.asarray(up, dtype=np.float64).reshape(-1)), np.float64)
    except (TypeError, ValueError) as err:
        raise BadCloudError(str(err)) from None


def cut_out(
    points: ArrayLike, request: PoseRequest, limits: Limits
) -> tuple[ArrayLike, Stripped | None]:
    """The cloud a request poses and classifies -> (its points, what was taken away or None):
    where ``up`` is given and ``strip`` is not false, the floor and walls a cut-out kept
    (``itnet.floor_and_walls``), measured in metres where the request names the unit. Raises
    BadCloudError for a bad cloud, ``up`` or ``viewpoint``, or ``strip`` without ``up``."""
    if request.strip is False or (request.up is None and request.strip is None):
        return points, None
    if request.up is None:
        raise BadCloudError(
            "strip needs 'up', which way is up in the cloud ([x, y, z]; 'x,y,z' in a query): "
            "a floor and its walls are found as level and upright planes"
        )
    cloud = validate_cloud(points, limits)
    viewpoint = None if request.viewpoint is None else validate_viewpoint(request.viewpoint)
    metres = None if request.units is None else metres_per_unit(request.units)
    stripped = strip_floor_and_walls(cloud, validate_up(request.up), viewpoint, metres)
    return cloud[stripped.keep], stripped
