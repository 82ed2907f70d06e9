"""``itnet eval``: the anytime accuracy curve on the test split, with a plot."""

from __future__ import annotations

import typer

from itnet.commands.request_options import REQUEST, request_options
from itnet.model.eval_config import EvalOptions


@request_options(EvalOptions, into="options")
def evaluate(options: EvalOptions = REQUEST) -> None:
    """Accuracy at (10°, 0.1 radius) for every iteration 0..N, median errors, CDF plot."""
    from itnet.model.eval_run import evaluate_model
    from itnet.model.input_error import InputError

    try:
        done = evaluate_model(options)
    except InputError as err:
        raise typer.BadParameter(str(err)) from None
    rep = done.anytime
    typer.echo("iteration  accuracy  rot<10°  trans<0.1  median rot°  median trans")
    for k in rep.iterations:
        typer.echo(
            f"{k:9d}  {rep.accuracy[k]:8.3f}  {rep.rotation_accuracy[k]:7.3f}  "
            f"{rep.translation_accuracy[k]:9.3f}  {rep.median_rotation_deg[k]:11.2f}  "
            f"{rep.median_translation[k]:12.4f}"
        )
    typer.echo(
        f"{rep.scans} scans of {done.objects} test objects ({done.orientation}); "
        f"wrote {done.report} and {done.plot}"
    )
