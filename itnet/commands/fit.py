"""``itnet fit ...``: the fits and measurements behind the shipped scene files and category table.

Each command's options are its config's fields (``itnet.model``); the work is the library
function beside the config. Needs the ``train`` extra (torch).

    itnet fit scene-classifier       # itnet/scene/scene_classifier.json
    itnet fit touching-cut           # itnet/scene/touching_cut.json
    itnet fit scene-centre           # itnet/scene/centre_along_floor.json
    itnet fit heights                # the height table of itnet.scene.height_prior
    itnet fit categories             # each category's symmetry and frame, measured
    itnet fit category-report DIR OUT
    itnet fit ablation               # the paper's ablation table on the chair
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from itnet.commands.request_options import REQUEST, request_options
from itnet.model.ablation import Ablation
from itnet.model.scene_centre_fit import SceneCentreFit
from itnet.model.scene_classifier_fit import SceneClassifierFit
from itnet.model.touching_cut_fit import TouchingCutFit

app = typer.Typer(
    help="Fit the scene files and measure the category table (needs the 'train' extra).",
    no_args_is_help=True,
    add_completion=False,
)
DATA = typer.Option(Path("../shared/data/modelnet10"), help="ModelNet10 root.")


@app.command("scene-classifier")
@request_options(SceneClassifierFit, into="config")
def scene_classifier(config: SceneClassifierFit = REQUEST) -> None:
    """Fit the scene classifier (names a cluster by its shape on the floor) and its threshold."""
    from itnet.model.scene_classifier_fit import fit_scene_classifier

    fit_scene_classifier(config)


@app.command("touching-cut")
@request_options(TouchingCutFit, into="config")
def touching_cut(config: TouchingCutFit = REQUEST) -> None:
    """Fit the cut judge (where two objects stand against each other) and its threshold."""
    from itnet.model.touching_cut_fit import fit_cut_judge

    fit_cut_judge(config)


@app.command("scene-centre")
@request_options(SceneCentreFit, into="config")
def scene_centre(config: SceneCentreFit = REQUEST) -> None:
    """Fit each pose model's scene correction (its object's centre along the floor)."""
    from itnet.model.scene_centre_fit import fit_centre_table

    try:
        table, stats = fit_centre_table(config)
    except ValueError as err:
        raise typer.BadParameter(str(err)) from None
    typer.echo(json.dumps(stats, indent=1))
    typer.echo(f"wrote {config.out}: {len(table.corrections)} model(s)")


@app.command("heights")
def heights(data: Path = DATA) -> None:
    """Measure the scenes' height table: each category's median height and its spread."""
    from itnet.model.heights import measure

    for name, (median, spread) in measure(data).items():
        typer.echo(f'    "{name}": ({median}, {spread}),')


@app.command("categories")
def categories(
    data: Path = DATA,
    category: list[str] = typer.Option(None, help="Categories (default: ModelNet10's ten)."),
    frame: str = typer.Option("modelnet", help="How the data's shapes are oriented."),
    shapes: int = typer.Option(80, min=1, help="Training shapes per category."),
) -> None:
    """Each category's measured symmetry, declared symmetry and how its shapes sit in the
    canonical frame (a Markdown table)."""
    from itnet.model.categories import FRAME_COLUMNS, MODELNET10, measured_frames

    rows = measured_frames(data, category or list(MODELNET10), frame, shapes)
    typer.echo("| " + " | ".join(FRAME_COLUMNS) + " |")
    typer.echo("|" + "---|" * len(FRAME_COLUMNS))
    for row in rows:
        typer.echo("| " + " | ".join(row) + " |")


@app.command("category-report")
def category_report(
    evals: Path = typer.Argument(..., help="Per-category evaluations (itnet eval's folders)."),
    out: Path = typer.Argument(..., help="Where the table, its JSON and the plot go."),
) -> None:
    """Every category's anytime accuracy in one table and one plot."""
    from itnet.model.category_report import write_report

    try:
        typer.echo(write_report(evals, out))
    except ValueError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None


@app.command("ablation")
@request_options(Ablation, into="config")
def ablation(config: Ablation = REQUEST) -> None:
    """The paper's ablation at reduced scale on the chair: a model per row, trained and measured
    on the test split (resumable: each row has its own run)."""
    from itnet.model.ablation import run_ablation, table

    typer.echo(table(run_ablation(config), config.steps))
