"""``CardChanges``: what to change on an exported pose model's card, each default with the
measurement that justifies it (``benchmarks.bench_ensemble``'s JSONs, ``itnet eval``'s
report.json). ``itnet.export.card_edit`` applies them; None leaves a field as it is.

    edit_card(Path("bed.onnx"), CardChanges(mirror_planes="x", without_mirror=off, with_mirror=on))

Torch-free, so the command line imports it when it starts; the typer options of ``itnet card``
are derived from its fields (``itnet.commands.request_options``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field


class CardChanges(BaseModel):
    """Changes to a pose model's card; with none, the card is only read."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mirror_planes: str | None = Field(
        None,
        description="set the category's planes of mirror symmetry: x (x = 0, left-right), z "
        "(z = 0, front-back), x,z, or none (`itnet fit categories` measures them)",
    )
    without_mirror: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble` JSON of one run with the card's planes off, "
        "beside --with-mirror",
    )
    with_mirror: Path | None = Field(
        None,
        description="the same with the planes on, on the same views: recorded as the card's "
        "mirror_evaluation",
    )
    mirror_fused: bool | None = Field(
        None, description="finish fused runs (the ensemble mode) by the planes too, by default"
    )
    verify_fused: bool | None = Field(
        None,
        description="anchor fused runs by the one that sits most firmly in its basin "
        "(itnet.basin), by default, where the budget holds the probes; needs its measurement "
        "(--with-verify)",
    )
    without_verify: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble --verify off` JSON of fused runs, beside "
        "--with-verify",
    )
    with_verify: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble --verify on` JSON of the same views "
        "(`--baseline` the first for the paired gain): recorded as the card's verify_evaluation",
    )
    recheck_runs: int | None = Field(
        None,
        ge=0,
        le=16,
        description="recheck a single run the category's verifier doubts with this many runs, "
        "by default (0: not by default); above 0 it needs its measurement (--with-recheck)",
    )
    without_recheck: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble --recheck off` JSON of one run, beside "
        "--with-recheck",
    )
    with_recheck: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble --recheck on` JSON of the same views "
        "(`--baseline` the first): recorded as the card's recheck_evaluation",
    )
    coarse_steps: str | None = Field(
        None,
        description="ITERATIONS,POINTS: the served schedule's first ITERATIONS steps on at most "
        "POINTS of each run's points, or none; a schedule needs its measurement (--with-plan)",
    )
    halving: str | None = Field(
        None,
        description="AT,KEEP: in the same schedule, after AT iterations only the KEEP runs the "
        "verifier finds likeliest go on, or none; needs its measurement (--with-plan)",
    )
    without_plan: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble --full` JSON of fused runs (every run on all "
        "its points every step), beside --with-plan",
    )
    with_plan: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble --full --coarse .. --halving ..` JSON of the "
        "same views (`--baseline` the first): recorded as the card's plan_evaluation",
    )
    recommended_ensemble: int | None = Field(
        None,
        ge=1,
        le=16,
        description="runs fused by default (the budget permitting); above 1 it needs "
        "--ensemble-report",
    )
    ensemble_report: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble` JSON measuring that many runs against one: "
        "recorded as the card's ensemble_evaluation",
    )
    requires_up: bool | None = Field(
        None,
        description="serve the model only to requests that give 'up' (which way is up in the "
        "cloud); needs --up-report",
    )
    up_report: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble --up` JSON of the card's default runs: recorded "
        "as the card's up_evaluation",
    )
    camera_report: Path | None = Field(
        None,
        description="`benchmarks.bench_ensemble` JSON of the card's default runs on views by a "
        "depth camera (--scanners RULE+SENSOR, the served measurement's split and budget, with "
        "--up where the card requires up): its views are added to the served evaluation",
    )
    up_free_steps: int | None = Field(
        None,
        ge=0,
        description="with the up direction given, run this many steps free before holding the "
        "pose upright",
    )
    report: Path | None = Field(
        None,
        description="an `itnet eval` report.json to record as the card's accuracy per "
        "iteration (as `itnet export --report`)",
    )
    out: Path | None = Field(None, description="write here instead of changing MODEL in place")
