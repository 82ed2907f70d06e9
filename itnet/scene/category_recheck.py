"""A scene object's category rechecked by the pose models' learned verifiers.

The classifiers name some scene objects wrongly, and surely: from the front a dresser is a flat
face, named a chair or a monitor. Each category's learned verifier (``model/verifier.py``)
tells a right pose of its category from a wrong one by how the cloud looks where the pose puts
it, and a cluster posed as a category it is not tends to look wrong there too. So where the
named category's verifier doubts the object's pose (logit below ``RECHECK_BELOW``), the object
is posed as its second candidate category as well (the same pipeline and finishing), and that
category is kept where its own verifier finds its pose likelier by more than
``RECHECK_MARGIN`` (and reported ``unsure``: it was ranked second). The second pose shares the
object's part of the scene's budget; the reply says ``category_recheck``: ``changed``,
``kept`` or ``budget`` (doubted, no time left).

An object whose base lies below the view (a chair before a level camera at head height, seen
from its seat up) is not rechecked (``base_out_of_view``): the verifiers learned views of whole
objects, and such a part looks wrong to its own category's verifier too (on validation scenes
the recheck would trade a right category for a wrong one 27 times for once the other way).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from itnet.basin import canonical_points
from itnet.pose.catalog import Catalog
from itnet.pose.recognition import pose_model_for
from itnet.pose.runtime import LoadedModel
from itnet.preprocess import cap_points, estimate_normalization, pose_to_normalized
from itnet.scene.posing import ObjectPose, posed_as

RECHECK_BELOW = 2.0  # a pose whose verifier logit is lower is doubted ...
RECHECK_MARGIN = 3.0  # ... and the second category kept where its logit is higher by this
MIN_RECHECK_MS = 4.0  # the least time left for the second pose ...
FINISH_MS = 3.0  # ... after this is kept for its finishing and its verifier's call


def pose_logit(model: LoadedModel, points: NDArray, pose: NDArray) -> float | None:
    """The logit (of the pose being right) of ``model``'s learned verifier for a cluster (K, 3)
    posed by T_canonical_from_input ``pose`` (4, 4), on a fixed draw of the verifier's number
    of points; None where the model has no verifier."""
    verifier = model.verifier
    if verifier is None:
        return None
    p = cap_points(np.asarray(points, dtype=np.float64), verifier.card.points,
                   np.random.default_rng(0))  # fmt: skip
    norm = estimate_normalization(p)
    pose_n = pose_to_normalized(pose, norm).astype(np.float32)
    return float(verifier.scores(canonical_points(norm.apply(p)[None], pose_n[None]))[0])


def rechecked(
    catalog: Catalog,
    seen: ObjectPose,
    points: NDArray,
    up: NDArray,
    viewpoint: NDArray,
    deadline: float,
    finish: Callable[[ObjectPose], ObjectPose],
    base_out_of_view: bool = False,
) -> ObjectPose:
    """A posed and finished object (``finish``: what the scene does to every pose, such as
    standing it on the floor) -> the same, or, where its verifier doubts it and the second
    category's verifier finds its own finished pose likelier by RECHECK_MARGIN, that one; the
    second pose, its finishing and its verifier's call must end by ``deadline``
    (``time.perf_counter()``). ``base_out_of_view``: whether the object's base lies below the
    view; such an object, where doubted, keeps its category."""
    model = None if seen.result is None else catalog.models[seen.result["model"]]
    logit = None if model is None or seen.pose is None else pose_logit(model, points, seen.pose)
    if logit is None or logit >= RECHECK_BELOW or len(seen.candidates) < 2:
        return seen
    if base_out_of_view:
        return _noted(seen, "base_out_of_view")
    second = seen.candidates[1]
    other_model = pose_model_for(second["category"], catalog.models)
    if other_model is None or other_model.verifier is None:
        return seen
    now = time.perf_counter()
    left_ms = (deadline - now) * 1e3 - FINISH_MS
    if left_ms < MIN_RECHECK_MS:
        return _noted(seen, "budget")
    # ranked second: an object whose category changes is reported unsure
    other = ObjectPose(second["category"], second["probability"], seen.candidates, True,
                       named_by=seen.named_by)  # fmt: skip
    other = posed_as(catalog, other, points, up, viewpoint, left_ms, now)
    if other.pose is None:
        return _noted(seen, "budget")
    other = finish(other)
    assert other.pose is not None
    other_logit = pose_logit(other_model, points, other.pose)
    if other_logit is not None and other_logit > logit + RECHECK_MARGIN:
        return _noted(other, "changed")
    return _noted(seen, "kept")


def _noted(seen: ObjectPose, outcome: str) -> ObjectPose:
    if seen.result is not None:
        seen.result = seen.result | {"category_recheck": outcome}
    return seen
