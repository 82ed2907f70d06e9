"""``itnet bench``: step latency by batch, points and threads, and the anytime loop's overhead."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import typer


def bench(
    model: str = typer.Option("chair", help="Model name."),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    repeats: int = typer.Option(200, help="Timed runs per configuration."),
) -> None:
    """Print a markdown table of median step times (onnxruntime) and the loop overhead."""
    from itnet.service.benchmark import loop_overhead, time_step_ms
    from itnet.service.models_in_process import get_model

    path = get_model(model, model_dir).path
    typer.echo(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
        f"model {path.name}"
    )
    typer.echo("| B×N | 1 thread (ms) | 2 threads (ms) | 2 threads per item (ms) |")
    typer.echo("|---|---|---|---|")
    for batch, points in ((1, 1024), (1, 4096), (8, 1024)):
        one = time_step_ms(path, batch, points, 1, repeats)
        two = time_step_ms(path, batch, points, 2, repeats)
        typer.echo(f"| {batch}×{points} | {one:.2f} | {two:.2f} | {two / batch:.2f} |")
    loop = loop_overhead(path, threads=2)
    typer.echo(
        f"\nanytime loop, 2 threads, 1024 points: {loop['loop_iteration_ms']:.3f} ms per "
        f"iteration vs raw step {loop['raw_step_ms']:.3f} ms "
        f"(overhead {loop['overhead_pct']:+.1f}%); per-request setup {loop['setup_ms']:.2f} ms"
    )
