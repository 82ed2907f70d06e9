"""The pose pipeline as a library: what every path of itnet (HTTP, stream, CLI, alignment, batch,
scenes, the page) runs, for embedding without a server.

    from itnet.pose import Catalog, PoseRequest

    catalog = Catalog.load()                                  # the shipped models, warmed up
    reply = catalog.pose(points, PoseRequest(budget_ms=20))   # the finished pose, as a dict
    for estimate in catalog.start(points, PoseRequest(budget_ms=200)):
        print(estimate.iteration, estimate.pose)              # T_canonical_from_input, 4x4

One job a module: ``request`` (PoseRequest: what a caller may ask), ``plan`` (a request turned
into a PosePlan once), ``stages`` (the finishing stages), ``loop`` (the one anytime loop),
``catalog`` (loaded models, ``start``: request -> run, and ``pose``: admitted beside the runs
posed at once, ``admission``), ``runtime`` (onnxruntime sessions and
model cards), ``recognition`` (``model: "auto"``), ``cloud`` and ``errors`` (what is refused and
why), ``reply`` (the JSON form). Names are imported lazily, so that ``itnet.pose.request`` stays
light for the clients (pydantic only, no onnxruntime).
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "Catalog": "itnet.pose.catalog",
    "PoseRequest": "itnet.pose.request",
    "PosePlan": "itnet.pose.plan",
    "plan": "itnet.pose.plan",
    "AnytimeRun": "itnet.pose.loop",
    "Estimate": "itnet.pose.reply",
    "PoseError": "itnet.pose.errors",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'itnet.pose' has no attribute {name!r}")
