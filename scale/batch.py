"""``itnet batch``'s engine: inputs -> Ray Data -> worker actors -> one table, resumably.

    items (paths or pairs not yet in the output)
      -> ray.data.from_items                       # blocks of ``batch_size`` items
      -> map_batches(Worker, concurrency=workers)  # actors: the model loaded once each
      -> iter_batches in the driver                # each finished batch written as a part
      -> BatchTable.finish                         # one Parquet / JSON Lines table

Locally (no ``address``) Ray starts with this machine's CPUs and each worker gets
``cpus // workers`` onnxruntime threads (1 when workers = cores: more threads than cores only
fight). With ``address`` the job runs on that cluster and each worker asks for ``threads`` CPUs.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from itnet.scale.table import BatchTable


@dataclass(frozen=True)
class BatchStats:
    """What a run did: items done now, skipped (already in the output), error rows among those
    done, rows in the output, and times."""

    done: int
    skipped: int
    errors: int
    rows: int
    seconds: float  # the whole run, Ray's start and the models' loading included
    # items a second once every worker had answered, by when the workers finished their batches
    # (0: too few batches to tell)
    steady_per_second: float


def worker_threads(workers: int, threads: int | None, address: str | None) -> int:
    """onnxruntime threads per worker: as given, else the local cores shared out, else 1."""
    if threads is not None:
        return threads
    if address is not None:
        return 1
    return max(1, (os.cpu_count() or 1) // workers)


def run_batch(
    worker: type,
    worker_args: dict[str, Any],
    items: list[dict[str, str]],
    table: BatchTable,
    key: tuple[str, ...],
    workers: int,
    address: str | None = None,
    threads: int = 1,
    batch_size: int = 32,
    progress: bool = True,
) -> BatchStats:
    """Run ``worker`` over the ``items`` not yet in ``table``; write and merge the rows."""
    done_keys = table.done()
    todo = [item for item in items if tuple(item[k] for k in key) not in done_keys]
    started = time.perf_counter()
    errors = rows_now = first_rows = 0
    first_at = last_at = 0.0
    seen: set[int] = set()  # workers that have answered
    if todo:
        import ray
        from tqdm import tqdm

        owned = not ray.is_initialized()  # a Ray already running in this process is used
        cpus = _start_ray(address, workers, threads) if owned else _quiet_data(workers, threads)
        bar = tqdm(total=len(items), initial=len(items) - len(todo), unit="cloud",
                   disable=not progress, file=sys.stderr, smoothing=0.1)  # fmt: skip
        try:
            blocks = max(workers, -(-len(todo) // batch_size))  # every worker gets work
            ds = ray.data.from_items(todo, override_num_blocks=min(blocks, len(todo)))
            ds = ds.map_batches(
                worker,
                fn_constructor_kwargs={**worker_args, "threads": threads},
                batch_size=batch_size,
                concurrency=workers,
                num_cpus=threads if address else min(threads, cpus / workers),
                batch_format="numpy",
            )
            for batch in ds.iter_batches(batch_size=None, batch_format="numpy"):
                rows = [json.loads(text) for text in batch["row"]]
                seen.update(int(w) for w in batch["worker"])
                done_at = float(np.max(batch["done_at"])) if len(rows) else 0.0
                if not first_at and len(seen) >= workers:  # all up: steady from here
                    first_at, first_rows = done_at, rows_now + len(rows)
                table.write_part(rows)
                errors += sum("error" in row for row in rows)
                rows_now += len(rows)
                bar.update(len(rows))
                last_at = max(last_at, done_at)
        finally:
            bar.close()
            if owned:
                ray.shutdown()
    total = table.finish()
    after_first = rows_now - first_rows
    return BatchStats(
        done=rows_now, skipped=len(items) - len(todo), errors=errors, rows=total,
        seconds=time.perf_counter() - started,
        steady_per_second=(after_first / (last_at - first_at)
                           if after_first > 0 and last_at > first_at else 0.0),
    )  # fmt: skip


def _start_ray(address: str | None, workers: int, threads: int) -> float:
    """Connect to ``address`` or start a local Ray; the CPUs it offers. Ray Data's own progress
    bars and logs are turned off (the batch shows one bar)."""
    import ray

    options: dict[str, Any] = {"log_to_driver": False, "logging_level": logging.ERROR,
                               "configure_logging": False}  # fmt: skip
    if address is None:
        cpus = os.cpu_count() or 1
        ray.init(num_cpus=cpus, include_dashboard=False, **options)
    else:
        ray.init(address=address, **options)
    return _quiet_data(workers, threads)


def _quiet_data(workers: int, threads: int) -> float:
    import ray
    from ray.data import DataContext

    context = DataContext.get_current()
    context.enable_progress_bars = False
    context.print_on_execution_start = False
    context.verbose_stats_logs = False
    logging.getLogger("ray.data").setLevel(logging.ERROR)
    return float(ray.cluster_resources().get("CPU", workers * threads))
