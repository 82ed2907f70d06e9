"""Aligning cloud A onto cloud B through their canonical poses (``itnet-align``, ``/v1/align``).

    from itnet.alignment import align
    from itnet.alignment.request import AlignRequest
    from itnet.pose import Catalog

    result = align(Catalog.load(), a, b, AlignRequest(model="chair", budget_ms=100))
    result.T_b_from_a                                  # 4x4, moves A onto B, B's units
    result.probability                                 # calibrated: how likely it is right

The family, one job each:

* ``request``: what an alignment asks for (``AlignRequest``), declared once;
* ``pipeline``: the steps: both clouds' served poses, the composed pose, rivals where it is in
  doubt, ICP, the likeliest (``align_clouds``);
* ``hypotheses``: the pure math: relative poses ``inv(T_cb) · S · T_ca`` for every pair of poses
  and symmetry turn, distinct candidates;
* ``choice``: each candidate's evidence, its calibrated probability, the choice;
* ``overlap``: how well A, moved by a candidate, lies on B (KD-tree overlap and RMSE);
* ``refine``: point-to-plane ICP with open3d (the optional ``refine`` extra);
* ``estimators``: where the poses come from: the pose pipeline in this process, both clouds
  posed together.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from itnet.alignment.pipeline import Alignment
    from itnet.alignment.request import AlignRequest
    from itnet.pose.catalog import Catalog


def align(
    catalog: Catalog,
    points_a: ArrayLike,
    points_b: ArrayLike,
    request: AlignRequest | None = None,
    refine: bool | None = None,
) -> Alignment:
    """T_b_from_a of clouds A (N, 3) and B (M, 3) as ``itnet-align`` gives it, in-process: both
    clouds posed by ``request``'s pose request (its model: a name, not ``auto``; default: the
    catalog's default model and the alignment's defaults), the composed pose, its rivals where it
    is in doubt, ICP where ``refine`` (default: the request's, else when open3d is installed).
    Raises ``itnet.alignment.pipeline.CloudEstimateError`` naming the cloud the pipeline
    refused."""
    from itnet.alignment.estimators import in_process_estimator
    from itnet.alignment.pipeline import align_clouds
    from itnet.alignment.refine import refine_wanted
    from itnet.alignment.request import AlignRequest

    request = request or AlignRequest()
    refine = refine_wanted(request.refine if refine is None else refine)
    card = catalog.model(request.model).card
    estimate = in_process_estimator(catalog, request.pose_request(card.name))
    return align_clouds(points_a, points_b, estimate, request.options(card, refine),
                        request.up_a, request.up_b)  # fmt: skip
