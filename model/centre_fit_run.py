"""``itnet centre-fit`` as a function: a pose model's object-centre correction fitted on its
category's training shapes (``itnet.model.centre_fit``), measured on the validation views, and
written into its card where asked.

The scans (occluded and paper views) are posed as served; one run without and with the
correction is measured on the validation views. A second correction that also takes the
direction toward the sensor serves requests that give ``viewpoint``. With ``up`` the runs are
held upright, the two corrections serve requests that give ``up`` (the second, those that give
both), and the card's own corrections are measured on the same upright runs beside them.

    done = fit_model_centre(Path("bed.onnx"), CentreFitOptions(views=1, val_views=2))
    done.results["paper"]["accuracy"], done.evaluation
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import onnx

from itnet.centre import CentreCorrection
from itnet.export.onnx_export import save_with_card
from itnet.model import centre_fit as fitting
from itnet.model.categories import Category, category
from itnet.model.category_set import training_scans, validation_scans
from itnet.model.centre_fit_config import CentreFitOptions
from itnet.model.data import ScanSet
from itnet.model.input_error import InputError
from itnet.model.scanner import ScanConfig, named_views
from itnet.pose.runtime import LoadedModel, load_model
from itnet.upright import sensed_ups

Results = dict[str, dict[str, Any]]
"""``centre_fit.measure``'s results by kind of view."""


@dataclass(frozen=True)
class CentreFitReport:
    """The two corrections fitted, their measurements by kind of view (``centre_fit.measure``),
    with ``up`` the card's own corrections measured on the same upright runs (``plain_results``,
    ``served_viewpoint_results``; empty where the card has none or without ``up``), the card's
    evaluation line, and the files written (None: not asked for)."""

    correction: CentreCorrection
    viewpoint_correction: CentreCorrection
    results: Results
    viewpoint_results: Results
    evaluation: str
    plain_results: Results = field(default_factory=dict)
    served_viewpoint_results: Results = field(default_factory=dict)
    report: Path | None = None
    written: Path | None = None


def fit_model_centre(
    model: Path, options: CentreFitOptions, log: Callable[[str], None] = lambda line: None
) -> CentreFitReport:
    """Fit, measure and (``options.write``) write ``model``'s centre corrections; ``log`` gets
    a line per kind of view posed. Raises ModelLoadError for a file that is not a pose model,
    InputError where too few training scans are posed right to fit on."""
    loaded = load_model(model)
    cat = category(loaded.card.category, loaded.card.symmetry)
    kinds = view_kinds(options.kinds, cat.name)
    served = []
    for i, (kind, scan) in enumerate(kinds.items()):
        seed = options.seed + i
        scans = training_scans(options.data, cat, options.views, seed, scan, options.cache)
        served.append(serve(loaded, scans, cat, options, i))
        log(f"{kind}: {len(scans.clouds)} training scans posed")
    try:
        correction = fitting.fit(served, options.ridge, options.max_rotation)
        # with up: the viewpoint correction of runs held upright (requests with both)
        with_viewpoint = fitting.fit(served, options.ridge, options.max_rotation, True)
    except ValueError as err:
        raise InputError(str(err)) from None
    done = measured(loaded, cat, kinds, options, correction, with_viewpoint)
    if options.report is not None:
        measurement = {
            "model": str(model),
            "up_error_deg": options.up,
            "results": done.results,
            "viewpoint_results": done.viewpoint_results,
            "plain_results": done.plain_results,
            "served_viewpoint_results": done.served_viewpoint_results,
            "evaluation": done.evaluation,
        }
        options.report.write_text(json.dumps(measurement, indent=1))
    written = write_corrections(model, loaded, done, options) if options.write else None
    return replace(done, report=options.report, written=written)


def view_kinds(names: str, category: str) -> dict[str, ScanConfig]:
    """The ScanConfig of each comma-separated view rule of ``names`` (``model.scanner``'s
    names, a camera's included). Raises InputError for a name it does not know."""
    try:
        return {name: named_views(name, category) for name in names.split(",")}
    except (KeyError, ValueError) as err:
        raise InputError(f"--kinds: {err}") from None


def serve(
    loaded: LoadedModel, scans: ScanSet, cat: Category, options: CentreFitOptions, stream: int
) -> fitting.ServedCentres:
    """``scans`` posed as served with ``options``' runs; with ``options.up``, each scan's up
    tilted by that error from a generator seeded by ``options.seed`` and ``stream``."""
    ups = None
    if options.up is not None:
        ups = sensed_ups(scans.poses, options.up, np.random.default_rng([options.seed, stream]))
    return fitting.served_centres(loaded, scans, cat.symmetry, options.ensemble, ups)


def measured(
    loaded: LoadedModel,
    cat: Category,
    kinds: dict[str, ScanConfig],
    options: CentreFitOptions,
    correction: CentreCorrection,
    with_viewpoint: CentreCorrection,
) -> CentreFitReport:
    """The two corrections (and, with up, the card's own) measured on the validation views of
    each kind, with the card's evaluation line."""
    results: Results = {}
    viewpoint_results: Results = {}
    plain_results: Results = {}
    served_viewpoint: Results = {}  # held runs: what requests with both get today
    for i, (kind, scan) in enumerate(kinds.items()):
        scans = validation_scans(
            options.data, cat, options.val_views, scan=scan, cache=options.cache
        )
        posed = serve(loaded, scans, cat, options, 100 + i)
        results[kind] = fitting.measure(posed, correction)
        if options.up is not None and loaded.centre is not None:  # what up requests get without
            plain_results[kind] = fitting.measure(posed, loaded.centre)
        if options.up is not None and loaded.centre_viewpoint is not None:  # ... with a viewpoint
            served_viewpoint[kind] = fitting.measure(posed, loaded.centre_viewpoint)
        viewpoint_results[kind] = fitting.measure(posed, with_viewpoint)
    evaluation = describe_fit(options, results, viewpoint_results, plain_results, served_viewpoint)
    return CentreFitReport(
        correction=correction,
        viewpoint_correction=with_viewpoint,
        results=results,
        viewpoint_results=viewpoint_results,
        evaluation=evaluation,
        plain_results=plain_results,
        served_viewpoint_results=served_viewpoint,
    )


def describe_fit(
    options: CentreFitOptions,
    results: Results,
    viewpoint_results: Results,
    plain_results: Results,
    served_viewpoint: Results,
) -> str:
    """The card's evaluation line of the fit: the correction, with up the card's plain one, the
    viewpoint correction, and with up the card's viewpoint one, each without and with."""
    runs = "one run" if options.ensemble == 1 else f"{options.ensemble} runs fused"
    not_kept = "" if options.keep_viewpoint else " (measured, not kept)"
    if options.up is None:
        viewpoint = f"the viewpoint correction{not_kept} (requests that give the sensor's position)"
        return f"{fitting.describe(results, runs=runs)}. " + fitting.describe(
            viewpoint_results, viewpoint, runs
        )
    runs += f", held upright by an up {options.up:g} deg off"
    measured_as = [
        (results, "the correction fitted held upright"),
        (plain_results, "the plain correction (fitted on runs not held)"),
        (
            viewpoint_results,
            f"the viewpoint correction fitted held upright{not_kept} (requests that give up "
            "and the sensor's position)",
        ),
        (served_viewpoint, "the viewpoint correction fitted on runs not held"),
    ]
    return ". ".join(fitting.describe(r, what, runs) for r, what in measured_as if r)


def write_corrections(
    model: Path, loaded: LoadedModel, done: CentreFitReport, options: CentreFitOptions
) -> Path:
    """Write the corrections and their evaluation into the card of ``model`` (at
    ``options.out``, else in place); with up, the upright ones, the others left as they are;
    without ``options.keep_viewpoint``, the card's viewpoint variant left as it is too."""
    if options.up is not None:
        names = ("centre_correction_up", "centre_correction_up_viewpoint", "centre_up_evaluation")
    else:
        names = ("centre_correction", "centre_correction_viewpoint", "centre_evaluation")
    correction, viewpoint, evaluation = names
    update = {correction: done.correction.to_dict(), evaluation: done.evaluation}
    if options.keep_viewpoint:
        update[viewpoint] = done.viewpoint_correction.to_dict()
    card = loaded.card.model_copy(update=update)
    return save_with_card(onnx.load(str(model)), card, options.out or model)
