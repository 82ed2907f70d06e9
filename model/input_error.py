"""``InputError``: what a build step (training, evaluation, export, a card's change, a centre
fit) refuses in what it is given, before or instead of doing its work."""

from __future__ import annotations


class InputError(ValueError):
    """An option's value, a file or a model that a build step cannot work with: an unknown
    choice, half of a measurement, a report that does not measure what it is given for, a model
    too inaccurate to fit on. The message names the option as the command line spells it
    (``--loss``); a command line reports it as a usage error (exit 2)."""
