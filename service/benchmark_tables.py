"""``itnet bench``'s tables as Markdown lines: step times by batch, points and threads, the anytime
loop's overhead, and replies a second with many requests at once (``itnet.service.benchmark``
measures; this module only arranges the rows)."""

from __future__ import annotations

import statistics
from pathlib import Path

from itnet.pose.runtime import LoadedModel
from itnet.service.benchmark import GOOD_ITERATIONS, concurrent_poses, loop_overhead, time_step_ms

ROUNDS = 3  # the models interleaved, a few rounds each; the median of the rounds is reported


def step_table(models: dict[str, LoadedModel], repeats: int) -> list[str]:
    """Median step time of each model at its own point count and the paper's shapes, with 1 and
    2 onnxruntime threads. The machine's speed drifts (other tenants of the host), so the models
    are interleaved over ROUNDS rounds and each row is the median of its rounds."""
    lines = [
        "| model | precision | B×N | 1 thread (ms) | 2 threads (ms) | 2 threads per item (ms) |",
        "|---|---|---|---|---|---|",
    ]
    shapes = {(1, m.card.points) for m in models.values()} | {(1, 1024), (1, 4096), (8, 1024)}
    for batch, points in sorted(shapes):
        times: dict[tuple[str, int], list[float]] = {}
        for _ in range(ROUNDS):
            for name, loaded in models.items():
                for threads in (1, 2):
                    ms = time_step_ms(
                        loaded.path, batch, points, threads, max(1, repeats // ROUNDS)
                    )
                    times.setdefault((name, threads), []).append(ms)
        for name, loaded in models.items():
            one, two = (statistics.median(times[(name, t)]) for t in (1, 2))
            lines.append(f"| {name} | {loaded.card.precision} | {batch}×{points} | {one:.2f} | "
                         f"{two:.2f} | {two / batch:.2f} |")  # fmt: skip
    return lines


def loop_lines(models: dict[str, LoadedModel]) -> list[str]:
    """Each model's anytime loop per iteration against its raw step, 2 threads."""
    lines = []
    for name, loaded in models.items():
        loop = loop_overhead(loaded.path, threads=2)
        lines.append(
            f"{name}: anytime loop, 2 threads, {loaded.card.points} points: "
            f"{loop['loop_iteration_ms']:.3f} ms per iteration vs raw step "
            f"{loop['raw_step_ms']:.3f} ms (overhead {loop['overhead_pct']:+.1f}%); "
            f"per-request setup {loop['setup_ms']:.2f} ms"
        )
    return lines


def load_table(
    model_dir: Path | None, clients: list[int], budget_ms: float, duration_s: float
) -> list[str]:
    """Replies a second and iterations a reply of the default model's default request, in this
    process (no HTTP), with each count of requests at once; steps batched into shared calls
    (the service's setting) and one call a step."""
    from itnet.cloud_io import read_cloud
    from itnet.pose.catalog import Catalog
    from itnet.pose.request import PoseRequest
    from itnet.pose.runtime import RuntimeOptions, default_model_dir, load_all

    folder = model_dir or default_model_dir()
    cloud = read_cloud(default_model_dir().parent / "examples" / "chair_a.ply")
    lines = [
        f"| batching | requests at once | replies/s | ≥ {GOOD_ITERATIONS} iterations/s | share of "
        "one request's | iterations a reply | refused | graph calls | steps a call |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    name = precision = ""
    for batching, jobs in (("on", RuntimeOptions().batch_jobs), ("off", 1)):
        models, classifier = load_all(folder, 2, True, None, RuntimeOptions(batch_jobs=jobs))
        catalog = Catalog(models, classifier)
        name = catalog.default_name() or sorted(models)[0]
        precision = models[name].card.precision
        up = [0.0, 1.0, 0.0] if models[name].card.requires_up else None
        request = PoseRequest(model=name, budget_ms=budget_ms, up=up)
        alone = None
        for count in clients:
            row = concurrent_poses(catalog, request, cloud, count, duration_s)
            alone = row["good_per_s"] if alone is None else alone
            share = f"{row['good_per_s'] / alone:.0%}" if alone else "-"
            lines.append(
                f"| {batching} | {count} | {row['replies_per_s']:.1f} | {row['good_per_s']:.1f} | "
                f"{share} | {row['iterations_mean']:.1f} | {row['refused']} | {row['calls']} | "
                f"{row['steps_a_call']:.2f} |"
            )
    shared = "An int8 graph shares no call (it quantizes each call's activations as a whole)."
    lines.append(
        f"model {name} ({precision}), {len(cloud)} points, budget {budget_ms:g} ms, "
        f"{duration_s:g} s a row; share: of the first row's replies with at least "
        f"{GOOD_ITERATIONS} iterations. " + (shared if precision == "int8" else "")
    )
    return lines
