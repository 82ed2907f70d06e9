"""``itnet centre-fit``: fit a pose model's centre correction and measure it on validation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer


def centre_fit(
    model: Path = typer.Argument(
        ..., help="An exported pose model (.onnx) of a ModelNet category."
    ),
    data: Path = typer.Option(Path("../shared/data/modelnet10"), help="ModelNet-style root."),
    views: int = typer.Option(3, min=1, help="Views per training shape (each of two view kinds)."),
    val_views: int = typer.Option(8, min=1, help="Views per validation shape, to measure it."),
    ridge: float = typer.Option(10.0, min=0.0, help="Ridge weight (standardised features)."),
    seed: int = typer.Option(4242, help="Seed of the training shapes' views."),
    ensemble: int = typer.Option(
        1,
        min=1,
        max=16,
        help="Pose the scans with this many runs fused (the card's default "
        "for a model served that way), to fit and to measure.",
    ),
    max_rotation: float = typer.Option(
        20.0,
        help="Fit on the training scans posed within this many degrees (a wrong basin's "
        "centre teaches nothing).",
    ),
    write: bool = typer.Option(
        False, help="Write the correction and its measurement into the card."
    ),
    out: Path | None = typer.Option(
        None, help="With --write: write here instead of changing MODEL."
    ),
    report: Path | None = typer.Option(None, help="Write the measurement (JSON) here."),
    cache: Path = typer.Option(Path("cache"), help="Cache of shapes and scans."),
    up: float | None = typer.Option(
        None,
        metavar="ERROR_DEG",
        help="Fit and measure the correction for requests that give the up direction: every "
        "scan's runs held upright by its up, tilted ERROR_DEG degrees from the truth (a gravity "
        "sensor's error); with --write it becomes the card's centre_correction_up, and its "
        "viewpoint variant centre_correction_up_viewpoint (requests that give both).",
    ),
) -> None:
    """Fit a model's object-centre correction on its category's training shapes and measure it.

    The scans are posed as served; one run without and with the correction is measured on the
    validation views. ``--write`` stores it in the card, and the service applies it after the
    last step. A second correction that also takes the direction toward the sensor serves
    requests that give ``viewpoint``; with ``--up`` the runs are held upright and the two serve
    requests that give ``up`` (the second, those that give both)."""
    import onnx

    from itnet.export.onnx_export import save_with_card
    from itnet.model import centre_fit as fitting
    from itnet.model.categories import category
    from itnet.model.category_set import training_scans, validation_scans
    from itnet.model.data import ScanSet
    from itnet.model.scanner import VIEW_RULES, scan_config
    from itnet.pose.runtime import ModelLoadError, load_model
    from itnet.upright import sensed_ups

    try:
        loaded = load_model(model)
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    card = loaded.card
    cat = category(card.category, card.symmetry)
    kinds = {kind: scan_config(VIEW_RULES[kind]) for kind in ("occluded", "paper")}

    def ups_of(scans: ScanSet, stream: int) -> np.ndarray | None:
        if up is None:
            return None
        return sensed_ups(scans.poses, up, np.random.default_rng([seed, stream]))

    served = []
    for i, (kind, scan) in enumerate(kinds.items()):
        scans = training_scans(data, cat, views, seed + i, scan, cache)
        served.append(
            fitting.served_centres(loaded, scans, cat.symmetry, ensemble, ups_of(scans, i))
        )
        typer.echo(f"{kind}: {len(scans.clouds)} training scans posed", err=True)
    try:
        correction = fitting.fit(served, ridge, max_rotation)
        # with up: the viewpoint correction of runs held upright (requests with both)
        with_viewpoint = fitting.fit(served, ridge, max_rotation, True)
    except ValueError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    results: dict[str, dict] = {}
    viewpoint_results: dict[str, dict] = {}
    plain_results: dict[str, dict] = {}
    served_viewpoint: dict[str, dict] = {}  # held runs: what requests with both get today
    for i, (kind, scan) in enumerate(kinds.items()):
        scans = validation_scans(data, cat, val_views, scan=scan, cache=cache)
        posed = fitting.served_centres(
            loaded, scans, cat.symmetry, ensemble, ups_of(scans, 100 + i)
        )
        results[kind] = fitting.measure(posed, correction)
        typer.echo(f"{kind}: {json.dumps(results[kind])}")
        if up is not None and loaded.centre is not None:  # what up requests get without it
            plain_results[kind] = fitting.measure(posed, loaded.centre)
            typer.echo(f"{kind}, the card's plain correction: {json.dumps(plain_results[kind])}")
        if up is not None and loaded.centre_viewpoint is not None:  # ... and with a viewpoint
            served_viewpoint[kind] = fitting.measure(posed, loaded.centre_viewpoint)
            typer.echo(
                f"{kind}, the card's viewpoint correction: {json.dumps(served_viewpoint[kind])}"
            )
        viewpoint_results[kind] = fitting.measure(posed, with_viewpoint)
        typer.echo(f"{kind}, with the viewpoint: {json.dumps(viewpoint_results[kind])}")
    runs = "one run" if ensemble == 1 else f"{ensemble} runs fused"
    if up is not None:
        runs += f", held upright by an up {up:g} deg off"
        evaluation = fitting.describe(results, "the correction fitted held upright", runs)
        if plain_results:
            evaluation += ". " + fitting.describe(
                plain_results, "the plain correction (fitted on runs not held)", runs
            )
        evaluation += ". " + fitting.describe(
            viewpoint_results,
            "the viewpoint correction fitted held upright (requests that give up and the "
            "sensor's position)",
            runs,
        )
        if served_viewpoint:
            evaluation += ". " + fitting.describe(
                served_viewpoint, "the viewpoint correction fitted on runs not held", runs
            )
    else:
        evaluation = (
            fitting.describe(results, runs=runs)
            + ". "
            + fitting.describe(
                viewpoint_results,
                "the viewpoint correction (requests that give the sensor's position)",
                runs,
            )
        )
    if report is not None:
        report.write_text(json.dumps({"model": str(model), "up_error_deg": up, "results": results,
                                      "viewpoint_results": viewpoint_results,
                                      "plain_results": plain_results,
                                      "served_viewpoint_results": served_viewpoint,
                                      "evaluation": evaluation}, indent=1))  # fmt: skip
    if write:
        if up is not None:  # the upright correction; the others are left as they are
            update = {
                "centre_correction_up": correction.to_dict(),
                "centre_correction_up_viewpoint": with_viewpoint.to_dict(),
                "centre_up_evaluation": evaluation,
            }
        else:
            update = {
                "centre_correction": correction.to_dict(),
                "centre_correction_viewpoint": with_viewpoint.to_dict(),
                "centre_evaluation": evaluation,
            }
        save_with_card(onnx.load(str(model)), card.model_copy(update=update), out or model)
        typer.echo(f"wrote the correction into {out or model}'s card", err=True)
