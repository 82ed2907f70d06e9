"""The ``itnet`` command line (typer). ``itnet-align`` is ``itnet align`` on its own."""

from __future__ import annotations

import typer

from itnet import __version__
from itnet.commands import (
    align,
    batch,
    bench,
    card,
    centre,
    classify,
    evaluate,
    export,
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


app.command("pose")(pose.pose)
app.command("scene")(scene.scene)
app.command("align")(align.align)
app.command("serve")(serve.serve)
app.command("train")(train.train)
app.command("average")(train.average)
app.command("eval")(evaluate.evaluate)
app.command("export")(export.export)
app.command("card")(card.card)
app.command("centre-fit")(centre.centre_fit)
app.command("bench")(bench.bench)
app.add_typer(batch.app, name="batch")
app.command("classify")(classify.classify)
app.command("classify-experiment")(classify.classify_experiment)
app.command("classify-export")(classify.classify_export)
app.command("classify-train")(classify.classify_train)
app.command("classify-size-prior")(classify.classify_size_prior)
app.command("models")(models.models)
app.command("verifier-train")(verifier.verifier_train)
app.command("verifier-export")(verifier.verifier_export)

align_app = typer.Typer(add_completion=False)
align_app.command()(align.align)
