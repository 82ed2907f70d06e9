"""One module per CLI command; heavy imports stay inside the command bodies."""

from __future__ import annotations

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
