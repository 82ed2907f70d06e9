"""``itnet classify FILE...`` (which category is each cloud) and the classifier's build commands:
``classify-train`` (one run), ``classify-export`` (a run to its served graph, measured),
``classify-experiment`` (the paper's classification table on partial ModelNet10) and
``classify-size-prior`` (the card's size prior). Each build command's options are its config's
fields; the work is the library function beside the config (``itnet.model.classify``,
``itnet.export``)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from itnet.commands import check_units
from itnet.commands.request_options import REQUEST, request_options, xyz_option
from itnet.export.classifier_build_config import ClassifierExportConfig
from itnet.model.classify.configs import (
    ClassifyExperimentConfig,
    ClassifyTrainConfig,
    SizePriorFitConfig,
)
from itnet.pose.request import PoseRequest

if TYPE_CHECKING:
    from itnet.export.classifier_build import ClassifierExportReport


def classify(
    files: list[Path] = typer.Argument(..., help="Cloud files: .ply .pcd .xyz .pts .txt .npy"),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    top: int = typer.Option(3, help="Candidates to print (most probable first)."),
    units: str | None = typer.Option(
        None, help=PoseRequest.field_help("units"), callback=check_units
    ),
    looks: int = typer.Option(
        1,
        min=1,
        max=16,
        help="Classify K turned random subsets of each cloud and average them "
        "(more accurate, about K times the time).",
    ),
    up: str | None = typer.Option(
        None,
        help="Which way is up in the clouds, 'x,y,z' (gravity): each is classified levelled, by "
        "the upright classifier where one is installed.",
        callback=xyz_option,
    ),
    viewpoint: str | None = typer.Option(
        None, help=PoseRequest.field_help("viewpoint"), callback=xyz_option
    ),
    strip: bool | None = typer.Option(
        None, "--strip/--no-strip", help=PoseRequest.field_help("strip")
    ),
    second_looks: int | None = typer.Option(
        None,
        min=1,
        max=16,
        help="A single look whose answer is unsure is followed by more, this many looks in all "
        "(1: never; default: the service's, 4): more accurate, that many times the time for "
        "those clouds.",
    ),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line."),
) -> None:
    """Print each cloud's category and probabilities. Bad files are reported and skipped (exit 2)."""
    from itnet.cloud_io import CloudReadError, read_cloud
    from itnet.commands.in_process import get_classifier
    from itnet.pose.cloud import Limits, cut_out
    from itnet.pose.errors import BadCloudError
    from itnet.pose.recognition import classify as recognise

    classifier = get_classifier(model_dir)
    request = PoseRequest(up=up, viewpoint=viewpoint, strip=strip, units=units)  # type: ignore[arg-type]
    failed = False
    for path in files:
        try:
            points, stripped = cut_out(read_cloud(path), request, Limits())
            result = recognise(
                classifier, points, top=top, units=units, looks=looks, up=up,
                **({} if second_looks is None else {"second_looks": second_looks}),
            )  # fmt: skip
        except (CloudReadError, BadCloudError) as err:
            message = str(err) if str(err).startswith(str(path)) else f"{path}: {err}"
            typer.echo(f"error: {message}", err=True)
            failed = True
            continue
        if as_json:
            taken = {} if stripped is None else {"stripped": stripped.as_dict()}
            typer.echo(json.dumps({"file": str(path), **result.as_dict(), **taken}))
        else:
            others = ", ".join(f"{c.category} {c.probability:.3f}" for c in result.candidates[1:])
            unsure = " (unsure)" if result.unsure else ""
            unsure += " (upright)" if result.upright else ""
            unsure += f" ({result.looks} looks)" if result.second_opinion else ""
            typer.echo(
                f"{path}: {result.category} {result.probability:.3f}{unsure}"
                + (f"; then {others}" if others else "")
                + f" ({result.elapsed_ms:.1f} ms)"
            )
    if failed:
        raise typer.Exit(2)


@request_options(ClassifyExperimentConfig, into="config")
def classify_experiment(config: ClassifyExperimentConfig = REQUEST) -> None:
    """Train every row of the table (resumable: finished rows are skipped), then write the
    report. Rows: none, T-Net (1, 2 iterations), T-Net + regulariser (1, 2), IT-Net (1, 2)."""
    from itnet.model.classify.experiment_run import run_experiment

    for path in run_experiment(config).written:
        typer.echo(f"wrote {path}")


@request_options(ClassifierExportConfig, into="config")
def classify_export(
    run: Path = typer.Argument(
        ...,
        help="A finished run folder (best.pt, result.json), or a shipped checkpoint "
        "(lab/weights/classifier.pt): its run is remade from the config it keeps.",
    ),
    config: ClassifierExportConfig = REQUEST,
) -> None:
    """Export a run's best classifier (canonicaliser included) to one ONNX graph, check it
    against torch on random clouds, then measure the graph itself on the run's validation and
    test views: its card carries that accuracy and the unsure threshold chosen on validation."""
    from itnet.export.classifier_build import export_classifier_run
    from itnet.model.input_error import InputError

    try:
        done = export_classifier_run(run, config)
    except InputError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    for line in export_lines(done):
        typer.echo(line)


def export_lines(done: ClassifierExportReport) -> list[str]:
    """What ``classify-export`` prints of its report: the graph and its measurements, then
    each file written beside it."""
    card = done.card
    torch_test = "not measured" if done.torch_test is None else f"{100 * done.torch_test:.1f}%"
    lines = [
        f"wrote {done.out} ({done.size_bytes / 1e6:.1f} MB, {card.precision}): "
        f"{card.transformer}, test accuracy {100 * card.accuracy:.1f}% on this graph "
        f"(torch: {torch_test}), validation {100 * float(card.training['validation']):.1f}% "
        f"(torch: {100 * done.torch_validation:.1f}%), threshold {card.threshold}; "
        f"max |onnx - torch| {done.max_difference:.2e} on a random cloud"
    ]
    if done.weights_out is not None:
        lines.append(f"wrote {done.weights_out} ({done.weights_bytes / 1e6:.1f} MB)")
    if done.report is not None:
        lines.append(f"test views at the threshold: {json.dumps(done.unsure)}; wrote {done.report}")
    if done.confusion is not None:
        lines.append(f"wrote {done.confusion}")
    return lines


@request_options(ClassifyTrainConfig, into="config")
def classify_train(config: ClassifyTrainConfig = REQUEST) -> None:
    """Train one classifier (resumable), e.g. the shipped one: a table row trained longer."""
    from itnet.model.classify.train_run import train_classifier

    done = train_classifier(config)
    test = done.test
    measured = (
        f"{100 * test['accuracy']:.1f}% ± {100 * test['standard_error']:.1f} "
        f"({test['scans']} views)"
        if test
        else "not measured (held back, or no test shapes)"
    )
    typer.echo(f"{done.variant}: validation {100 * done.validation_accuracy:.1f}%, test {measured}")


@request_options(SizePriorFitConfig, into="config")
def classify_size_prior(config: SizePriorFitConfig = REQUEST) -> None:
    """Fit the classifier's size prior on views of the training shapes (ModelNet's units read
    as inches, or real sizes), measure top-1 with and without it on views of the validation or
    test shapes (4 a shape, seeded), and with --write store both in the classifier's card: then
    a request that gives its cloud's unit (``units``) lets the size count (``itnet.size_prior``)."""
    from itnet.model.classify.size_prior_fit import fit_classifier_size_prior
    from itnet.model.input_error import InputError

    try:
        done = fit_classifier_size_prior(config)
    except InputError as err:
        raise typer.BadParameter(str(err)) from None
    for name, median, scale in zip(done.classes, done.prior.log_median, done.prior.log_scale):
        typer.echo(f"{name:12s} RMS radius of a view: median {math.exp(median):.3f} m, "
                   f"log spread {scale:.2f}")  # fmt: skip
    typer.echo(f"{done.split}: {json.dumps(done.scores)}")
    if done.current is not None:  # the card's prior now, on the same views
        typer.echo(f"{done.split}, the card's prior now: {json.dumps(done.current)}")
    if done.written is not None:
        typer.echo(f"wrote the size prior into {done.written}'s card")
