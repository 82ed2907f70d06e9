"""``itnet bench``: step latency by batch, points and threads, the anytime loop's overhead, and
poses a second with many requests at once, their steps batched into shared calls and not."""

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
                    ms = time_step_ms(
                        loaded.path, batch, points, threads, max(1, repeats // rounds)
                    )
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
    counts = [int(c) for c in clients.split(",") if c.strip()]
    if counts:
        load_table(model_dir, counts, budget_ms, duration_s)


def load_table(model_dir: Path | None, clients: list[int], budget_ms: float,
               duration_s: float) -> None:  # fmt: skip
    """Replies a second and iterations a reply of the default model's default request, in this
    process (no HTTP), with each count of requests at once; steps batched into shared calls
    (the service's setting) and one call a step."""
    from itnet.cloud_io import read_cloud
    from itnet.pose.catalog import Catalog
    from itnet.pose.request import PoseRequest
    from itnet.pose.runtime import RuntimeOptions, default_model_dir, load_all
    from itnet.service.benchmark import GOOD_ITERATIONS, concurrent_poses

    folder = model_dir or default_model_dir()
    cloud = read_cloud(default_model_dir().parent / "examples" / "chair_a.ply")
    typer.echo(
        f"\n| batching | requests at once | replies/s | ≥ {GOOD_ITERATIONS} iterations/s | share of "
        "one request's | iterations a reply | refused | graph calls | steps a call |"
    )
    typer.echo("|---|---|---|---|---|---|---|---|---|")
    name = precision = ""
    for batching, jobs in (("on", RuntimeOptions().batch_jobs), ("off", 1)):
        models, classifier = load_all(folder, 2, True, None, RuntimeOptions(batch_jobs=jobs))
        catalog = Catalog(models, classifier)
        name = catalog.default_name() or sorted(models)[0]
        precision = models[name].card.precision
        request = PoseRequest(model=name, budget_ms=budget_ms,
                              up=[0.0, 1.0, 0.0] if models[name].card.requires_up else None)  # fmt: skip
        alone = None
        for count in clients:
            row = concurrent_poses(catalog, request, cloud, count, duration_s)
            alone = row["good_per_s"] if alone is None else alone
            share = f"{row['good_per_s'] / alone:.0%}" if alone else "-"
            typer.echo(
                f"| {batching} | {count} | {row['replies_per_s']:.1f} | {row['good_per_s']:.1f} | "
                f"{share} | {row['iterations_mean']:.1f} | {row['refused']} | {row['calls']} | "
                f"{row['steps_a_call']:.2f} |"
            )
    typer.echo(
        f"model {name} ({precision}), {len(cloud)} points, budget {budget_ms:g} ms, "
        f"{duration_s:g} s a row; share: of the first row's replies with at least "
        f"{GOOD_ITERATIONS} iterations. "
        + (
            "An int8 graph shares no call (it quantizes each call's activations as a whole)."
            if precision == "int8"
            else ""
        )
    )
