"""``itnet bench``: step latency by batch, points and threads, and the anytime loop's overhead."""

from __future__ import annotations

import statistics
from pathlib import Path

import typer


def bench(
    model: list[str] | None = typer.Option(
        None, help="Model names (repeat the option for several; default: every model)."
    ),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    repeats: int = typer.Option(200, help="Timed runs per configuration."),
) -> None:
    """Print a markdown table of median step times (onnxruntime) and the loop overhead."""
    from itnet.commands.in_process import all_models, get_model
    from itnet.cpu import cpu_description
    from itnet.service.benchmark import loop_overhead, time_step_ms

    typer.echo(f"machine: {cpu_description()}")
    typer.echo(
        "| model | precision | B×N | 1 thread (ms) | 2 threads (ms) | 2 threads per item (ms) |"
    )
    typer.echo("|---|---|---|---|---|---|")
    names = model or sorted(all_models(model_dir))
    paths = {name: get_model(name, model_dir) for name in names}
    # The machine's speed drifts (other tenants of the host): interleave the models, a few
    # rounds each, and report the median of the rounds, so the rows compare like with like.
    rounds = 3
    # The models' own point counts (what the service feeds them), and the paper's shapes.
    shapes = {(1, loaded.card.points) for loaded in paths.values()} | {(1, 1024), (1, 4096),
                                                                       (8, 1024)}  # fmt: skip
    for batch, points in sorted(shapes):
        times: dict[tuple[str, int], list[float]] = {}
        for _ in range(rounds):
            for name, loaded in paths.items():
                for threads in (1, 2):
                    ms = time_step_ms(loaded.path, batch, points, threads, repeats // rounds)
                    times.setdefault((name, threads), []).append(ms)
        for name, loaded in paths.items():
            one, two = (statistics.median(times[(name, t)]) for t in (1, 2))
            typer.echo(
                f"| {name} | {loaded.card.precision} | {batch}×{points} | {one:.2f} | "
                f"{two:.2f} | {two / batch:.2f} |"
            )
    for name, loaded in paths.items():
        loop = loop_overhead(loaded.path, threads=2)
        typer.echo(
            f"\n{name}: anytime loop, 2 threads, {loaded.card.points} points: "
            f"{loop['loop_iteration_ms']:.3f} ms "
            f"per iteration vs raw step {loop['raw_step_ms']:.3f} ms "
            f"(overhead {loop['overhead_pct']:+.1f}%); per-request setup {loop['setup_ms']:.2f} ms"
        )
