"""``itnet bench``: step latency by batch, points and threads, the anytime loop's overhead, and
poses a second with many requests at once, their steps batched into shared calls and not."""

from __future__ import annotations

from pathlib import Path

import typer


def bench(
    model: list[str] | None = typer.Option(
        None, help="Model names (repeat the option for several; default: every model)."
    ),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    repeats: int = typer.Option(200, help="Timed runs per configuration."),
    clients: str = typer.Option(
        "1,16,64", help="Requests posed at once, one row each ('': leave the load table out)."
    ),
    budget_ms: float = typer.Option(20.0, min=1.0, help="budget_ms of the load table's requests."),
    duration_s: float = typer.Option(3.0, min=0.1, help="Seconds per load row."),
) -> None:
    """Print markdown tables of median step times (onnxruntime), the loop overhead, and the
    default model's replies a second with 1, 16 and 64 requests at once, batching on and off."""
    from itnet.commands.in_process import all_models, get_model
    from itnet.cpu import cpu_description
    from itnet.service.benchmark_tables import load_table, loop_lines, step_table

    typer.echo(f"machine: {cpu_description()}")
    names = model or sorted(all_models(model_dir))
    models = {name: get_model(name, model_dir) for name in names}
    typer.echo("\n".join(step_table(models, repeats)))
    for line in loop_lines(models):
        typer.echo(f"\n{line}")
    counts = [int(c) for c in clients.split(",") if c.strip()]
    if counts:
        typer.echo("\n" + "\n".join(load_table(model_dir, counts, budget_ms, duration_s)))
