"""Aligning cloud A onto cloud B through their canonical poses (``itnet-align``, ``/v1/align``).

    from itnet.alignment import align
    from itnet.pose import Catalog, PoseRequest

    result = align(Catalog.load(), a, b, PoseRequest(model="chair"))
    result.T_b_from_a                                  # 4x4, moves A onto B, B's units

The family, one job each:

* ``pipeline``: the steps: each cloud's served pose and its runs, hypotheses, ICP, the chosen
  alignment (``align_clouds``);
* ``hypotheses``: the pure math: relative poses ``inv(T_cb) · S · T_ca`` for every pair of poses
  and symmetry turn, distinct candidates, the choice, confidence;
* ``overlap``: how well A, moved by a candidate, lies on B (KD-tree overlap and RMSE);
* ``refine``: point-to-plane ICP with open3d (the optional ``refine`` extra);
* ``estimators``: where the poses come from: the pose pipeline in-process or a running service.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from itnet.alignment.pipeline import Alignment
    from itnet.pose.catalog import Catalog
    from itnet.pose.request import PoseRequest


def align(
    catalog: Catalog,
    points_a: ArrayLike,
    points_b: ArrayLike,
    request: PoseRequest,
    refine: bool | None = None,
    up_a: ArrayLike | None = None,
    up_b: ArrayLike | None = None,
) -> Alignment:
    """T_b_from_a of clouds A (N, 3) and B (M, 3) as ``itnet-align`` gives it, in-process: each
    cloud posed by ``request`` (its model: a name, not ``auto``), the category's symmetric
    hypotheses, ICP where ``refine`` (default: when open3d is installed). Raises
    ``itnet.alignment.pipeline.CloudEstimateError`` naming the cloud the pipeline refused."""
    from itnet.alignment.estimators import in_process_estimator
    from itnet.alignment.hypotheses import category_symmetry
    from itnet.alignment.pipeline import AlignOptions, align_clouds
    from itnet.alignment.refine import RefineUnavailable, require_open3d

    if refine is None:
        try:
            require_open3d()
            refine = True
        except RefineUnavailable:
            refine = False
    card = catalog.model(request.model).card
    options = AlignOptions(symmetry=category_symmetry(card.category, card.symmetry), refine=refine)
    estimate = in_process_estimator(catalog, request)
    return align_clouds(points_a, points_b, estimate, options, up_a, up_b)
