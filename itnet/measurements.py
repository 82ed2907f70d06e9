"""A model's measurements as numbers with their protocol, and the one line of text each renders.

A card keeps what was measured of its model as ``Measurement`` records: what (the runs fused, the
pose with the up direction given, a finishing stage switched off and on), on which split and kind
of views, within which budget, on what machine, and per kind of views the scans, the accuracy at
(10 deg, 0.1 radius) in percent, the accuracy without the thing measured where it was, and the
standard errors. ``Measurement.text()`` is the card's evaluation line (``itnet models``,
``GET /v1/models``); ``Measurement.parse`` reads such a line back (cards written as text only).

    m = Measurement.parse("ensemble", card.ensemble_evaluation)
    m.result("paper").accuracy        # 85.8
    m.text() == card.ensemble_evaluation
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Kind = Literal["ensemble", "up", "mirror", "recheck", "verify", "plan"]
KINDS: tuple[Kind, ...] = ("ensemble", "up", "mirror", "recheck", "verify", "plan")
AT = "at (10 deg, 0.1 radius)"
# A finishing stage's words in the line, and what its share of scans says.
SWITCHES: dict[str, tuple[str, str]] = {
    "mirror": ("the mirror planes", "finished in time"),
    "recheck": ("the recheck", "rechecked"),
    "verify": ("verify", "verified in time"),
    "plan": ("the coarse first steps and the halving", "of the work"),
}
FUSED_KINDS = ("verify", "plan")  # measured on fused runs


class ViewResult(BaseModel):
    """One kind of views' figures (percentages at (10 deg, 0.1 radius))."""

    model_config = ConfigDict(extra="forbid")

    views: str = Field(description="the kind of views: occluded, surface, paper, a RULE+SENSOR")
    runs: int = Field(default=1, ge=1, description="runs fused per pose")
    scans: int = Field(ge=1)
    accuracy: float = Field(description="percent right, as measured (with the thing measured)")
    before: float | None = Field(
        default=None, description="percent right without it (one run, for the runs fused)"
    )
    gain: float | None = Field(default=None, description="paired gain over 'before', points")
    gain_stderr: float | None = Field(default=None, description="its standard error, points")
    stderr: float | None = Field(default=None, description="the accuracy's standard error, points")
    share: float | None = Field(
        default=None, description="percent of the scans the stage got to within the budget"
    )


class Measurement(BaseModel):
    """What was measured of a model, how, and the figures per kind of views."""

    model_config = ConfigDict(extra="forbid")

    kind: Kind = Field(
        description="ensemble: the runs fused against one; up: the pose with the up direction "
        "given; mirror, recheck, verify: that finishing stage off and on; plan: the card's "
        "coarse first steps and halving against every run on all its points every step"
    )
    split: str = Field(description="'test', or 'val' (views of held-out training shapes)")
    budget_ms: float = Field(gt=0, description="each pose's budget")
    machine: str = Field(description="where it was measured, e.g. 'x86_64, 2 cores'")
    up_error_deg: float | None = Field(
        default=None, description="how far the up given was tilted from the truth (kind 'up')"
    )
    results: list[ViewResult]

    def result(self, views: str) -> ViewResult:
        """The figures of one kind of views (KeyError where it was not measured)."""
        for row in self.results:
            if row.views == views:
                return row
        raise KeyError(views)

    def text(self) -> str:
        """The card's evaluation line."""
        render = {"ensemble": _ensemble_text, "up": _up_text}.get(self.kind, _switch_text)
        return render(self)

    @classmethod
    def parse(cls, kind: Kind, text: str) -> Measurement:
        """An evaluation line of ``kind`` -> its Measurement; ValueError for a line of another
        shape. ``parse(kind, line).text() == line`` for every line ``text()`` writes."""
        head, sep, tail = text.partition(f", {AT}: " if kind in ("ensemble", "up") else f" {AT}: ")
        found = re.fullmatch(r"(?s)(.*) \[([^\]]+)\]", tail)
        if not sep or found is None:
            raise ValueError(f"not a {kind} evaluation line: {text[:80]!r}")
        parts, machine = found.group(1), found.group(2)
        parse = {"ensemble": _ensemble, "up": _up}.get(kind)
        fields = parse(head, parts) if parse else _switch(kind, head, parts)
        return cls(kind=kind, machine=machine, **fields)


def _number(text: str) -> float:
    return float(text.replace("−", "-"))


def _ensemble_text(m: Measurement) -> str:
    runs = m.results[0].runs
    parts = ", ".join(
        f"{r.views} {r.accuracy:.1f}% (one run {r.before:.1f}%, {r.gain:+.1f} ± "
        f"{r.gain_stderr:.1f}; {r.scans} scans)"
        for r in m.results
    )
    return (f"{runs} runs fused, within {m.budget_ms:g} ms, on the {m.split} views, {AT}: "
            f"{parts} [{m.machine}]")  # fmt: skip


def _ensemble(head: str, parts: str) -> dict:
    found = re.fullmatch(r"(\d+) runs fused, within ([\d.]+) ms, on the (\w+) views", head)
    if found is None:
        raise ValueError(f"not an ensemble evaluation: {head!r}")
    runs = int(found.group(1))
    row = re.compile(r"(\S+) ([\d.]+)% \(one run ([\d.]+)%, ([+-][\d.]+) ± ([\d.]+); (\d+) scans\)")
    results = [
        ViewResult(
            views=v,
            runs=runs,
            accuracy=float(a),
            before=float(b),
            gain=_number(g),
            gain_stderr=float(s),
            scans=int(n),
        )
        for v, a, b, g, s, n in row.findall(parts)
    ]
    return {"split": found.group(3), "budget_ms": float(found.group(2)), "results": results}


def _up_text(m: Measurement) -> str:
    runs = m.results[0].runs
    said = "one run" if runs == 1 else f"{runs} runs fused"
    parts = ", ".join(
        f"{r.views} {r.accuracy:.1f}% ± {r.stderr:.1f} ({r.scans} scans)" for r in m.results
    )
    return (f"{said}, the up direction given (tilted {m.up_error_deg:g} deg from the truth), "
            f"within {m.budget_ms:g} ms, on the {m.split} views, {AT}: {parts} [{m.machine}]")  # fmt: skip


def _up(head: str, parts: str) -> dict:
    found = re.fullmatch(
        r"(one run|(\d+) runs fused), the up direction given \(tilted ([\d.]+) deg from the "
        r"truth\), within ([\d.]+) ms, on the (\w+) views",
        head,
    )
    if found is None:
        raise ValueError(f"not an up evaluation: {head!r}")
    runs = 1 if found.group(2) is None else int(found.group(2))
    row = re.compile(r"(\S+) ([\d.]+)% ± ([\d.]+) \((\d+) scans\)")
    results = [
        ViewResult(views=v, runs=runs, accuracy=float(a), stderr=float(s), scans=int(n))
        for v, a, s, n in row.findall(parts)
    ]
    return {"split": found.group(5), "budget_ms": float(found.group(4)),
            "up_error_deg": float(found.group(3)), "results": results}  # fmt: skip


def _switch_text(m: Measurement) -> str:
    words, share_words = SWITCHES[m.kind]
    fused = m.kind in FUSED_KINDS and any(r.runs > 1 for r in m.results)  # a plan: maybe one
    parts = []
    for r in m.results:
        gain = "" if r.gain is None else f"{r.gain:+.1f} ± {r.gain_stderr:.1f}, "
        share = "" if r.share is None else f", {r.share:.0f}% {share_words}"
        label = f"{r.views} {r.runs} runs" if fused else r.views
        parts.append(f"{label} {r.before:.1f}% -> {r.accuracy:.1f}% ({gain}{r.scans} scans{share})")
    return (f"{'fused runs' if fused else 'one run'} within {m.budget_ms:g} ms on the {m.split} "
            f"views, without and with {words}, {AT}: " + ", ".join(parts) + f" [{m.machine}]")  # fmt: skip


def _switch(kind: Kind, head: str, parts: str) -> dict:
    words, share_words = SWITCHES[kind]
    found = re.fullmatch(
        rf"(one run|fused runs) within ([\d.]+) ms on the (\w+) views, without and with "
        rf"{re.escape(words)},",
        head,
    )
    if found is None:
        raise ValueError(f"not a {kind} evaluation: {head!r}")
    row = re.compile(
        r"(\S+)(?: (\d+) runs)? ([\d.]+)% -> ([\d.]+)% \((?:([+-][\d.]+) ± ([\d.]+), )?(\d+) "
        rf"scans(?:, (\d+)% {re.escape(share_words)})?\)"
    )
    results = [
        ViewResult(
            views=v,
            runs=int(k) if k else 1,
            before=float(b),
            accuracy=float(a),
            gain=_number(g) if g else None,
            gain_stderr=float(s) if s else None,
            scans=int(n),
            share=float(p) if p else None,
        )
        for v, k, b, a, g, s, n, p in row.findall(parts)
    ]
    return {"split": found.group(3), "budget_ms": float(found.group(2)), "results": results}


class AnytimeProtocol(BaseModel):
    """How a card's ``accuracy`` (per iteration, one run) was measured: ``views`` random views
    of each test shape by a view rule, in full SO(3) and random units, held upright by an up
    ``up_error_deg`` off where given; ``points`` a run. ``text()`` is the card's ``evaluation``
    line, ``parse`` reads it back."""

    model_config = ConfigDict(extra="forbid")

    scans: int = Field(ge=1)
    views: int = Field(ge=1, description="random views a test shape")
    scanner: str = Field(description="the view rule: occluded, paper, surface, base_hidden, ...")
    up_error_deg: float | None = Field(
        default=None, description="the up given this far off the truth, the runs held upright"
    )
    category: str
    split: str = "test"
    points: int = Field(ge=1, description="points a run sees")

    def text(self) -> str:
        held = (
            ""
            if self.up_error_deg is None
            else f", the up direction given ({self.up_error_deg:g} deg off the truth), held upright"
        )
        return (
            f"{self.scans} partial scans ({self.views} random {self.scanner} views, full SO(3), "
            f"random units{held}) of the {self.category} {self.split} split, {self.points} points"
        )

    @classmethod
    def parse(cls, text: str) -> AnytimeProtocol:
        """An ``evaluation`` line -> its protocol; ValueError for a line of another shape."""
        found = re.fullmatch(
            r"(\d+) partial scans \((\d+) random (\S+) views, full SO\(3\), random units"
            r"(?:, the up direction given \(([\d.]+) deg off the truth\), held upright)?\) of the "
            r"(\S+) (\w+) split, (\d+) points",
            text,
        )
        if found is None:
            raise ValueError(f"not an anytime evaluation line: {text[:80]!r}")
        scans, views, scanner, up, category, split, points = found.groups()
        return cls(scans=int(scans), views=int(views), scanner=scanner,
                   up_error_deg=None if up is None else float(up), category=category,
                   split=split, points=int(points))  # fmt: skip
