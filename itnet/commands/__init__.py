"""One module per CLI command; heavy imports stay inside the command bodies."""

from __future__ import annotations

from pathlib import Path

import typer


def check_units(value: str | None) -> str | None:
    """typer callback: None or a unit ``itnet.size_prior.metres_per_unit`` knows (its message
    for any other)."""
    from itnet.size_prior import metres_per_unit

    if value is not None:
        try:
            metres_per_unit(value)
        except ValueError as err:
            raise typer.BadParameter(str(err)) from None
    return value


def parse_mirror_planes(text: str | None, default: tuple[str, ...] | list[str]) -> list[str]:
    """--mirror-planes 'x', 'x,z' or 'none'; None: ``default`` -> the card's planes."""
    from itnet.mirror import MIRROR_PLANES

    if text is None:
        return list(default)
    planes = [] if text.strip() == "none" else [t.strip() for t in text.split(",")]
    if any(p not in MIRROR_PLANES for p in planes) or len(set(planes)) != len(planes):
        raise typer.BadParameter(f"--mirror-planes {text!r}: give x, z or x,z (each once), or none")
    return planes


def ensemble_evaluation(recommended: int, report: Path | None) -> str:
    """--recommended-ensemble K with --ensemble-report JSON -> the card's ensemble_evaluation
    line ('' for one run without a report); K above 1 needs the report that measured it."""
    import json

    from itnet.model_card import describe_ensemble

    if report is None:
        if recommended > 1:
            raise typer.BadParameter(
                "a recommended ensemble needs its measurement: --ensemble-report"
            )
        return ""
    try:
        return describe_ensemble(json.loads(report.read_text()), recommended)
    except (KeyError, ValueError) as err:
        raise typer.BadParameter(f"--ensemble-report: {err}") from None
