"""``itnet card MODEL.onnx``: show or change what an exported pose model's card says about its
category, without touching its weights (the card is the graph's metadata)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import typer

from itnet.commands import ensemble_evaluation, parse_mirror_planes


def card(
    model: Path = typer.Argument(..., help="An exported pose model (.onnx)."),
    mirror_planes: str | None = typer.Option(
        None,
        help="Set the category's planes of mirror symmetry: x (x = 0, left-right), z (z = 0, "
        "front-back), x,z, or none (`python -m itnet.model.categories` measures them).",
    ),
    without_mirror: Path | None = typer.Option(
        None, help="`benchmarks.bench_ensemble` JSON of one run with the card's planes off ..."
    ),
    with_mirror: Path | None = typer.Option(
        None, help="... and on, on the same views: recorded as the card's mirror_evaluation."
    ),
    mirror_fused: bool | None = typer.Option(
        None,
        "--mirror-fused/--no-mirror-fused",
        help="Finish fused runs (the ensemble mode) by the planes too, by default.",
    ),
    verify_fused: bool | None = typer.Option(
        None,
        "--verify-fused/--no-verify-fused",
        help="Anchor fused runs by the one that sits most firmly in its basin (itnet.basin), "
        "by default, where the budget holds the probes; needs its measurement (--with-verify).",
    ),
    without_verify: Path | None = typer.Option(
        None, help="`benchmarks.bench_ensemble --verify off` JSON of fused runs ..."
    ),
    with_verify: Path | None = typer.Option(
        None,
        help="... and `--verify on` on the same views (`--baseline` the first for the paired "
        "gain): recorded as the card's verify_evaluation.",
    ),
    recheck_runs: int | None = typer.Option(
        None,
        min=0,
        max=16,
        help="Recheck a single run the category's verifier doubts with this many runs, by "
        "default (0: not by default); above 0 it needs its measurement (--with-recheck).",
    ),
    without_recheck: Path | None = typer.Option(
        None, help="`benchmarks.bench_ensemble --recheck off` JSON of one run ..."
    ),
    with_recheck: Path | None = typer.Option(
        None,
        help="... and `--recheck on` on the same views (`--baseline` the first): recorded as the "
        "card's recheck_evaluation.",
    ),
    recommended_ensemble: int | None = typer.Option(
        None,
        min=1,
        max=16,
        help="Runs fused by default (the budget permitting); above 1 it needs --ensemble-report.",
    ),
    ensemble_report: Path | None = typer.Option(
        None,
        help="`benchmarks.bench_ensemble` JSON measuring that many runs against one: recorded as "
        "the card's ensemble_evaluation.",
    ),
    requires_up: bool | None = typer.Option(
        None,
        "--requires-up/--no-requires-up",
        help="Serve the model only to requests that give 'up' (which way is up in the cloud); "
        "needs --up-report.",
    ),
    up_report: Path | None = typer.Option(
        None,
        help="`benchmarks.bench_ensemble --up` JSON of the card's default runs: recorded as the "
        "card's up_evaluation.",
    ),
    up_free_steps: int | None = typer.Option(
        None,
        min=0,
        help="With the up direction given, run this many steps free before holding the pose "
        "upright.",
    ),
    report: Path | None = typer.Option(
        None,
        help="report.json of `itnet eval` to record as the card's accuracy per iteration "
        "(as `itnet export --report`).",
    ),
    out: Path | None = typer.Option(None, help="Write here instead of changing MODEL in place."),
) -> None:
    """Print the card (JSON); with options, write the changed card into the model file."""
    import onnx

    from itnet.export.onnx_export import save_with_card
    from itnet.model_card import (
        ModelCard,
        describe_anytime,
        describe_mirror,
        describe_recheck,
        describe_up,
        describe_verify,
    )
    from itnet.pose.runtime import ModelLoadError, load_any

    try:
        current = load_any(model, warm_up=False).card
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    if not isinstance(current, ModelCard):
        writer = "classify-export" if current.kind == "classifier" else "verifier-export"
        typer.echo(f"error: {model} is a {current.kind}; its card is written by {writer}",
                   err=True)  # fmt: skip
        raise typer.Exit(2)
    update: dict[str, object] = {}
    planes = parse_mirror_planes(mirror_planes, current.mirror_planes)
    if mirror_planes is not None:
        update["mirror_planes"] = planes
    if recommended_ensemble is not None:
        update["recommended_ensemble"] = recommended_ensemble
        update["ensemble_evaluation"] = ensemble_evaluation(recommended_ensemble, ensemble_report)
    elif ensemble_report is not None:
        raise typer.BadParameter("--ensemble-report measures --recommended-ensemble: give both")
    if mirror_fused is not None:
        if mirror_fused and not planes:
            raise typer.BadParameter("--mirror-fused needs mirror planes on the card")
        update["mirror_fused"] = mirror_fused
    verify_text = _switch_evaluation("verify", without_verify, with_verify, describe_verify)
    if verify_text is not None:
        update["verify_evaluation"] = verify_text
    recheck_text = _switch_evaluation("recheck", without_recheck, with_recheck, describe_recheck)
    if recheck_text is not None:
        update["recheck_evaluation"] = recheck_text
    if recheck_runs is not None:
        if recheck_runs and not (update.get("recheck_evaluation") or current.recheck_evaluation):
            raise typer.BadParameter("--recheck-runs needs its measurement: --with-recheck")
        update["recheck_runs"] = recheck_runs
    if verify_fused is not None:
        if verify_fused and not (update.get("verify_evaluation") or current.verify_evaluation):
            raise typer.BadParameter("--verify-fused needs its measurement: --with-verify")
        update["verify_fused"] = verify_fused
    mirror_text = _switch_evaluation("mirror", without_mirror, with_mirror, describe_mirror)
    if mirror_text is not None:
        update["mirror_evaluation"] = mirror_text
    if report is not None:
        update["accuracy"], update["evaluation"] = describe_anytime(json.loads(report.read_text()))
    if up_report is not None:
        k = current.recommended_ensemble if recommended_ensemble is None else recommended_ensemble
        try:
            update["up_evaluation"] = describe_up(json.loads(up_report.read_text()), k)
        except (KeyError, ValueError) as err:
            raise typer.BadParameter(f"--up-report: {err}") from None
    if up_free_steps is not None:
        update["up_free_steps"] = up_free_steps
    if requires_up is not None:
        if requires_up and not (up_report or current.up_evaluation):
            raise typer.BadParameter("--requires-up needs its measurement: --up-report")
        update["requires_up"] = requires_up
    if not planes:
        update["mirror_fused"] = False  # no planes: nothing to finish fused runs by
    changed = current.model_copy(update=update)
    if changed != current:
        save_with_card(onnx.load(str(model)), changed, out or model)
    typer.echo(changed.model_dump_json(indent=1))


def _switch_evaluation(
    name: str,
    without: Path | None,
    with_it: Path | None,
    describe: Callable[[dict, dict], str],
) -> str | None:
    """``--without-NAME`` and ``--with-NAME`` (two ``benchmarks.bench_ensemble`` JSONs) -> the
    card's evaluation line of that finish by ``describe``; None where neither is given."""
    if (without is None) != (with_it is None):
        raise typer.BadParameter(f"give both --without-{name} and --with-{name}, or neither")
    if without is None or with_it is None:
        return None
    try:
        return describe(json.loads(without.read_text()), json.loads(with_it.read_text()))
    except (KeyError, ValueError) as err:
        raise typer.BadParameter(f"--with-{name}: {err}") from None
