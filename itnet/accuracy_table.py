"""The README's accuracy table, rendered from the models' cards: each category as served by
default (its card's runs and finishes, 50 ms on 2 cores), % right at (10 deg, 0.1 radius) on
the held-out test views, from the card's measurements (``itnet.measurements``): views by a
depth camera first (``itnet card --camera-report``), the clean renders beside them.

    itnet models --table       # the table, as the README shows it
"""

from __future__ import annotations

from collections.abc import Sequence

from itnet.measurements import Measurement
from itnet.service.schemas import ModelInfo

CAMERA = "occluded+kinect_v2"  # the realistic setting, first: occluded views by a Kinect v2
VIEWS = (CAMERA, "occluded", "surface", "paper")
HEADER = (
    "| category | symmetry | runs fused | occluded views, Kinect v2 | occluded views | "
    "surface views | paper views | paper views, `up` given | `viewpoint` centre |"
)


def _served(info: ModelInfo) -> Measurement | None:
    """The measurement of the model as served by default: with up where the card requires it,
    else its runs fused (a single run's default has none of its own)."""
    kind = "up" if info.requires_up else "ensemble"
    return next((m for m in info.measurements if m.kind == kind), None)


def _cell(measurement: Measurement | None, views: str, bold: bool) -> str:
    try:
        value = f"{measurement.result(views).accuracy:.1f}%" if measurement else "–"
    except KeyError:
        return "–"
    return f"**{value}**" if bold and measurement else value


def _viewpoint(info: ModelInfo) -> str:
    """Whether a request's viewpoint finishes the centre (a card that needs up: with up)."""
    if info.centre_viewpoint or (info.requires_up and info.centre_up_viewpoint):
        return "yes"
    return "yes, with `up`" if info.centre_up_viewpoint else "–"


def accuracy_table(models: Sequence[ModelInfo]) -> list[str]:
    """One row per category's own model (models named after their category), those served
    without up first, in the order given."""
    own = [m for m in models if m.name == m.category]
    rows = [HEADER, "|---|---|---|---|---|---|---|---|---|"]
    for info in sorted(own, key=lambda m: m.requires_up):
        served = _served(info)
        up = next((m for m in info.measurements if m.kind == "up"), None)
        name = info.category.replace("_", " ") + (" (needs `up`)" if info.requires_up else "")
        with_up = "as listed" if info.requires_up else _cell(up, "paper", bold=False)
        cells = [_cell(served, views, bold=views != "surface") for views in VIEWS]
        rows.append(f"| {name} | {info.symmetry} | {info.recommended_ensemble} | "
                    f"{' | '.join(cells)} | {with_up} | {_viewpoint(info)} |")  # fmt: skip
    return rows
