"""One module per CLI command; heavy imports stay inside the command bodies."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import typer

if TYPE_CHECKING:
    from pydantic import BaseModel

Request = TypeVar("Request", bound="BaseModel")

UNITS_HELP = (
    "The clouds' unit, if known: m, cm, mm, in or ft. With --model auto the cloud's size then "
    "counts toward its category as well as its form (a night stand is smaller than a dresser)."
)


def check_xyz(value: str | None) -> list[float] | None:
    """typer callback: 'x,y,z' -> [x, y, z] (three finite numbers), or a usage error."""
    if value is None:
        return None
    try:
        point = [float(v) for v in value.split(",")]
    except ValueError:
        point = []
    if len(point) != 3 or not all(math.isfinite(v) for v in point):
        raise typer.BadParameter(f"expected three numbers 'x,y,z', got {value!r}")
    return point


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


def from_options(kind: type[Request], **options: Any) -> Request:
    """The CLI's options (text for 'x,y,z' directions) -> a request of ``kind`` (``PoseRequest``,
    ``AlignRequest``), or a typer error (exit 2) saying which option is wrong."""
    from pydantic import ValidationError

    try:
        return kind.model_validate(options, strict=False)
    except ValidationError as err:
        first = err.errors(include_url=False)[0]
        name = "--" + str(first["loc"][0]).replace("_", "-") if first["loc"] else "options"
        typer.echo(f"error: {name}: {first['msg']}", err=True)
        raise typer.Exit(2) from None
