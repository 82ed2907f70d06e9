"""``itnet models``: the installed models and what their cards say (the CLI twin of
``GET /v1/models``)."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def models(
    model_dir: Path | None = typer.Option(
        None, help="Folder of .onnx models (default: the ones shipped in the package)."
    ),
    as_json: bool = typer.Option(
        False, "--json", help="Print GET /v1/models's JSON (step_ms measured here)."
    ),
) -> None:
    """List the models with category, symmetry, precision, points and measured accuracy."""
    import asyncio

    from itnet.pose.runtime import ModelLoadError, default_model_dir, load_models
    from itnet.service.api.routes.system import models as models_route
    from itnet.service.metrics import Metrics
    from itnet.service.settings import Settings
    from itnet.service.state import ServiceState

    folder = model_dir or default_model_dir()
    try:
        # The service's own loader: the same cards, warmed up so step_ms is this machine's.
        loaded = load_models(folder, threads=2, warm_up=True)
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    state = ServiceState(Settings(model_dir=folder), Metrics(), models=loaded)
    state.load()  # as at the service's start-up: the default model, the classifier if any
    reply = asyncio.run(models_route(state))  # the reply of GET /v1/models itself
    if as_json:
        typer.echo(json.dumps(reply.model_dump()))
        return
    rows = [
        ("name", "category", "symmetry", "mirror", "centre", "up", "precision", "points", "runs",
         "verifier", "accuracy", "step", ""),
    ]  # fmt: skip
    for info in reply.models:
        rows.append(
            (
                info.name,
                info.category,
                info.symmetry,
                ",".join(info.mirror_planes) or "-",
                _centre(
                    info.centre, info.centre_viewpoint, info.centre_up, info.centre_up_viewpoint
                ),
                "needed" if info.requires_up else "-",
                info.precision,
                str(info.points),
                str(info.recommended_ensemble),
                _verifier(
                    info.verifier, info.verify_fused, info.recheck_runs, info.recommended_ensemble
                ),
                _accuracy(info.accuracy, info.recommended_iterations),
                f"{info.step_ms:.2f} ms",
                "default" if info.default else "",
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for row in rows:
        typer.echo("  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip())
    if reply.auto is not None:
        typer.echo(
            f"auto: a classifier of {len(reply.auto.classes)} categories "
            f"({', '.join(reply.auto.classes)}) picks the pose model (--model auto)"
            + (
                "; an upright classifier joins it where the cloud's up is given (--up)"
                if reply.auto.upright is not None
                else ""
            )
        )
    typer.echo(
        f"({len(reply.models)} model(s) in {folder}; runs: fused per estimate by default, as "
        "many as the budget holds; mirror: the planes (x: left-right, z: front-back) a single "
        "run's final pose is finished by, fused runs' too where --json says mirror_fused; centre: "
        "the final pose's object centre is finished by the card's correction (+vp: another for "
        "requests that give the sensor's position, +up for those that give up, +upvp for those "
        "that give both); up: 'needed' "
        "where a request must say which way is up in its cloud (--up); verifier: where the "
        "category has a learned verifier, what it does by default (verify: fused runs anchored "
        "on the likeliest, verify-if-fused where the default is one run; recheck:N, a doubted "
        "single run rechecked by N runs); "
        "accuracy: one run's, at (10 deg, 0.1 radius), before the mirror, see --json)"
    )


def _verifier(name: str | None, verify: bool, recheck_runs: int, runs: int) -> str:
    """The verifier column: '-' without one, else what the card has it do by default: 'verify'
    where the default fuses runs, 'verify-if-fused' where it is one run (a request for several
    gets it), 'recheck:N' for a doubted single run."""
    if name is None:
        return "-"
    verifies = ["verify" if runs > 1 else "verify-if-fused"] if verify else []
    uses = verifies + ([f"recheck:{recheck_runs}"] if recheck_runs else [])
    return "+".join(uses) or "loaded"


def _accuracy(accuracy: dict[str, float], iterations: int) -> str:
    """'49.7% at 10 it.' (the card's figure at the recommended count), or '-' when unmeasured."""
    value = accuracy.get(str(iterations))
    return "-" if value is None else f"{100 * value:.1f}% at {iterations} it."


def _centre(plain: bool, viewpoint: bool, up: bool = False, up_viewpoint: bool = False) -> str:
    """'yes', 'yes+vp', 'vp' (only for requests that give the sensor's position), each with
    '+up' where another is fitted for requests that give up ('up' alone: only for those) and
    '+upvp' for those that give both, or '-'."""
    kinds = [
        kind
        for kind, has in (("yes", plain), ("vp", viewpoint), ("up", up), ("upvp", up_viewpoint))
        if has
    ]
    return "+".join(kinds) or "-"
