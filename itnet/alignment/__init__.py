"""Aligning cloud A onto cloud B through their canonical poses (``itnet-align``, ``/v1/align``).

The family, one job each:

* ``pipeline``: the steps: IT-Net from several starts on each cloud, hypotheses, ICP, the chosen
  alignment (``align_clouds``);
* ``hypotheses``: the pure math: relative poses ``inv(T_cb) · S · T_ca`` for every pair of runs
  and symmetry turn, distinct candidates, confidence;
* ``overlap``: how well A, moved by a candidate, lies on B (KD-tree overlap and RMSE);
* ``refine``: point-to-plane ICP with open3d (the optional ``refine`` extra);
* ``estimators``: where the poses come from: IT-Net in-process or a running service.
"""
