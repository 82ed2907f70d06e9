"""The ``itnet`` command line (typer). ``itnet-align`` is ``itnet align`` on its own."""

from __future__ import annotations

import typer

from itnet import __version__
from itnet.commands import (
    align,
    batch,
    bench,
    build,
    card,
    centre,
    classify,
    compact,
    evaluate,
    export,
    fit,
    models,
    pose,
    scene,
    serve,
    train,
    verifier,
)

app = typer.Typer(
    help="Anytime pose estimation and alignment of partial point clouds (IT-Net).",
    no_args_is_help=True,
    add_completion=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"itnet {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """itnet: poses of partial scans in their category's canonical frame, refined anytime."""


USE = "Using it"
MEASURE = "Training and measuring"
BUILD = "Building models"

# (name, function, panel, one-line help for the command list; the command's own --help has more)
# fmt: off
COMMANDS = [
    ("pose", pose.pose, USE, "Pose each cloud file in its category's canonical frame."),
    ("scene", scene.scene, USE, "Find the objects of a depth image or scene cloud, each posed."),
    ("align", align.align, USE, "Align cloud A onto cloud B (T_b_from_a), optionally refined by ICP."),
    ("classify", classify.classify, USE, "Name each cloud's category, with its probability."),
    ("serve", serve.serve, USE, "Serve the HTTP/WebSocket API and the web page."),
    ("models", models.models, USE, "List the installed models: category, symmetry, accuracy."),
    ("train", train.train, MEASURE, "Train a pose network on fresh partial scans (resumable)."),
    ("eval", evaluate.evaluate, MEASURE, "Measure a checkpoint or ONNX model on held-out scans."),
    ("export", export.export, MEASURE, "Export a checkpoint to an ONNX model with its card."),
    ("bench", bench.bench, MEASURE, "Time one step of each model and the loop's overhead."),
    ("build", build.build, BUILD, "Rebuild a category's shipped model from its data (resumable)."),
    ("average", train.average, BUILD, "Average checkpoints of one network."),
    ("card", card.card, BUILD, "Print a model's card, or write changes into it."),
    ("centre-fit", centre.centre_fit, BUILD, "Fit and measure a model's object-centre correction."),
    ("classify-train", classify.classify_train, BUILD, "Train one category classifier."),
    ("classify-export", classify.classify_export, BUILD, "Export a classifier run to ONNX and measure it."),
    ("classify-experiment", classify.classify_experiment, BUILD, "Train and report the transformer comparison table."),
    ("classify-size-prior", classify.classify_size_prior, BUILD, "Fit the classifier's size prior per category."),
    ("verifier-train", verifier.verifier_train, BUILD, "Train a category's pose verifier."),
    ("verifier-export", verifier.verifier_export, BUILD, "Export a pose verifier to ONNX."),
    ("compact", compact.compact, BUILD, "Store a model file's weights as float16 (half the size)."),
]
# fmt: on
for name, command, panel, summary in COMMANDS:
    app.command(name, rich_help_panel=panel, short_help=summary)(command)
app.add_typer(
    batch.app,
    name="batch",
    rich_help_panel=USE,
    short_help="Pose or align large collections of clouds on Ray Data.",
)
app.add_typer(
    fit.app,
    name="fit",
    rich_help_panel=BUILD,
    short_help="Fit the scene files (classifier, cut judge, corrections), measure the categories.",
)

align_app = typer.Typer(add_completion=False)
align_app.command()(align.align)
