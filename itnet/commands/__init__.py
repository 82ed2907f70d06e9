"""One module per CLI command; heavy imports stay inside the command bodies."""

from __future__ import annotations

import typer

UNITS_HELP = (
    "The clouds' unit, if known: m, cm, mm, in or ft. With --model auto the cloud's size then "
    "counts toward its category as well as its form (a night stand is smaller than a dresser)."
)


def check_units(value: str | None) -> str | None:
    """typer callback: None or a unit ``itnet.size_prior`` knows."""
    from itnet.size_prior import METRES_PER_UNIT

    if value is not None and value not in METRES_PER_UNIT:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(METRES_PER_UNIT)}")
    return value
