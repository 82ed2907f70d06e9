"""What a pose model's card records, read from the files that measured it: the mirror planes
from their text form, and the card's evaluation lines from ``itnet eval``'s report.json and
``benchmarks.bench_ensemble``'s JSONs (``itnet.model_card``'s ``describe_*`` write the lines).

Shared by the export of a checkpoint (``export/checkpoint_export.py``) and the change of an
exported model's card (``export/card_edit.py``). A file that does not measure what it is given
for is refused with InputError naming its option (``--ensemble-report``).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

from itnet.measurements import Measurement
from itnet.mirror import MIRROR_PLANES
from itnet.model.input_error import InputError
from itnet.model_card import (
    describe_anytime,
    describe_ensemble,
    describe_up,
    ensemble_measurement,
    up_measurement,
)


def mirror_planes(text: str | None, default: Sequence[str]) -> list[str]:
    """'x', 'x,z' or 'none' -> the card's planes; None: ``default``."""
    if text is None:
        return list(default)
    planes = [] if text.strip() == "none" else [t.strip() for t in text.split(",")]
    if any(p not in MIRROR_PLANES for p in planes) or len(set(planes)) != len(planes):
        raise InputError(f"--mirror-planes {text!r}: give x, z or x,z (each once), or none")
    return planes


def ensemble_evaluation(recommended: int, report: Path | None) -> str:
    """The card's ``ensemble_evaluation`` of K = ``recommended`` runs fused, measured by
    ``report`` ('' for one run without a report); K above 1 needs the report that measured it."""
    if report is None:
        if recommended > 1:
            raise InputError("a recommended ensemble needs its measurement: --ensemble-report")
        return ""
    try:
        return describe_ensemble(json.loads(report.read_text()), recommended)
    except (KeyError, ValueError) as err:
        raise InputError(f"--ensemble-report: {err}") from None


def anytime_evaluation(report: Path) -> tuple[dict[str, float], str]:
    """An ``itnet eval`` report.json -> (the card's ``accuracy`` per iteration, its
    ``evaluation``)."""
    return describe_anytime(json.loads(report.read_text()))


def up_evaluation(report: Path, runs: int) -> str:
    """The card's ``up_evaluation`` of the card's default ``runs``, from a
    ``benchmarks.bench_ensemble --up`` JSON."""
    try:
        return describe_up(json.loads(report.read_text()), runs)
    except (KeyError, ValueError) as err:
        raise InputError(f"--up-report: {err}") from None


def switch_evaluation(
    name: str,
    without: Path | None,
    with_it: Path | None,
    describe: Callable[[dict, dict], str],
) -> str | None:
    """``--without-NAME`` and ``--with-NAME`` (two ``benchmarks.bench_ensemble`` JSONs) -> the
    card's evaluation line of that finish by ``describe``; None where neither is given."""
    if (without is None) != (with_it is None):
        raise InputError(f"give both --without-{name} and --with-{name}, or neither")
    if without is None or with_it is None:
        return None
    try:
        return describe(json.loads(without.read_text()), json.loads(with_it.read_text()))
    except (KeyError, ValueError) as err:
        raise InputError(f"--with-{name}: {err}") from None


def with_camera_views(served: str, kind: str, report: Path, runs: int) -> str:
    """The card's served evaluation line (``kind`` 'ensemble' or 'up', of ``runs``) with the
    views that ``report`` (a ``benchmarks.bench_ensemble`` JSON of views by depth cameras,
    ``RULE+SENSOR``) measured added, or replacing the same views; the rest kept. The report
    must be of the same split and budget (and, for 'up', the same error of up)."""
    try:
        current = Measurement.parse(kind, served)  # type: ignore[arg-type]
        measure = ensemble_measurement if kind == "ensemble" else up_measurement
        added = measure(json.loads(report.read_text()), runs)
    except (KeyError, ValueError) as err:
        raise InputError(f"--camera-report: {err}") from None
    if (added.split, added.budget_ms, added.up_error_deg) != (
        current.split, current.budget_ms, current.up_error_deg,
    ):  # fmt: skip
        raise InputError(
            f"--camera-report: measured on the {added.split} split within {added.budget_ms:g} "
            f"ms, the card's on the {current.split} split within {current.budget_ms:g} ms"
            + ("" if added.up_error_deg == current.up_error_deg else ", with another up error")
        )
    if not all("+" in row.views for row in added.results):
        raise InputError("--camera-report: views by a depth camera only (RULE+SENSOR)")
    views = {row.views for row in added.results}
    kept = [row for row in current.results if row.views not in views]
    return current.model_copy(update={"results": [*added.results, *kept]}).text()
