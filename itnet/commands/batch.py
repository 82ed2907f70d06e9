"""``itnet batch pose|align|scene``: poses, alignments or scenes of whole collections on Ray Data.

One table out (Parquet, or JSON Lines by the suffix), a row per cloud (pair, scene) with the
fields of ``itnet pose --json`` (``itnet align --json``, ``itnet scene --json``); a file that
cannot be used becomes a row with an ``error``. Resumable: run the same command again after a
stop and it skips what is written (``itnet.scale.table``). Needs the ``ray`` extra:
``pip install 'itnet[ray]'``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NoReturn

import typer

from itnet.alignment.request import AlignRequest
from itnet.commands import recordings as rec
from itnet.commands import scene as scene_command
from itnet.commands.request_options import REQUEST, request_options
from itnet.pose.request import PoseRequest
from itnet.scene.request import SceneRequest

app = typer.Typer(
    help="Poses, alignments or scenes of many files on Ray Data (needs the 'ray' extra).",
    no_args_is_help=True,
    add_completion=False,
)

OUTPUT_HELP = "Output table: .parquet or .jsonl (parts in <output>.parts/ until done)."
WORKERS_HELP = "Worker actors, each with its own copy of the model."
RAY_HELP = "Address of a running Ray cluster (default: start Ray on this machine)."
THREADS_HELP = "onnxruntime threads per worker (default: local cores // workers; 1 on a cluster)."


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def _require_ray() -> None:
    try:
        import pyarrow  # noqa: F401
        import ray  # noqa: F401
    except ImportError as err:
        _fail(f"itnet batch needs the 'ray' extra (pip install 'itnet[ray]'): {err}")


@app.command("pose")
@request_options(PoseRequest)
def pose(
    inputs: list[str] = typer.Argument(..., help="Cloud files, folders (recursive) or globs."),
    output: Path = typer.Option(..., "--output", "-o", help=OUTPUT_HELP),
    workers: int = typer.Option(1, min=1, help=WORKERS_HELP),
    ray_address: str | None = typer.Option(None, "--ray", help=RAY_HELP),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    threads: int | None = typer.Option(None, min=1, help=THREADS_HELP),
    batch_size: int = typer.Option(32, min=1, help="Clouds per worker call."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
    request: PoseRequest = REQUEST,
) -> None:
    """The canonical pose of every cloud, as `itnet pose --json` gives it, in one table."""
    _require_ray()
    from itnet.commands.in_process import get_catalog, get_classifier, get_model
    from itnet.scale.inputs import InputError, expand_inputs
    from itnet.scale.workers import PoseWorker

    try:
        files = expand_inputs(inputs)
    except InputError as err:
        _fail(str(err))
    model = str(request.model)
    if get_catalog(model_dir).is_auto(model):
        get_classifier(model_dir)  # exit 2 for a folder without a classifier
    else:
        get_model(model, model_dir)  # exit 2 if unknown
    args = {"model": model, "model_dir": _dir(model_dir), "request": request.model_dump()}
    _run(PoseWorker, args, [{"file": f} for f in files], ("file",), output, workers,
         ray_address, threads, batch_size, progress, "clouds")  # fmt: skip


@app.command("align")
@request_options(AlignRequest)
def align(
    manifest: Path = typer.Argument(
        ...,
        help="Pairs: CSV with columns a,b, or .jsonl {a, b}; optional up_a, up_b ('x,y,z': which "
        "way is up in each cloud, over --up-a/--up-b; a model that requires up needs them).",
    ),
    output: Path = typer.Option(..., "--output", "-o", help=OUTPUT_HELP),
    workers: int = typer.Option(1, min=1, help=WORKERS_HELP),
    ray_address: str | None = typer.Option(None, "--ray", help=RAY_HELP),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    threads: int | None = typer.Option(None, min=1, help=THREADS_HELP),
    batch_size: int = typer.Option(8, min=1, help="Pairs per worker call."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
    request: AlignRequest = REQUEST,
) -> None:
    """T_b_from_a of every pair of a manifest, as `itnet align --json` gives it, in one table."""
    _require_ray()
    from itnet.alignment.refine import RefineUnavailable, refine_wanted
    from itnet.commands.in_process import get_model
    from itnet.scale.inputs import InputError, read_manifest
    from itnet.scale.workers import AlignWorker

    try:
        pairs = read_manifest(manifest)
    except InputError as err:
        _fail(str(err))
    try:
        refine = refine_wanted(request.refine, lambda why: typer.echo(
            f"note: no ICP refinement: {why}", err=True))  # fmt: skip
    except RefineUnavailable as err:
        _fail(str(err))
    model = str(request.model)
    get_model(model, model_dir)  # exit 2 if unknown
    asked = request.model_copy(update={"refine": refine}).model_dump()
    args = {"model": model, "model_dir": _dir(model_dir), "request": asked}
    items = [{"cloud_a": a, "cloud_b": b, "up_a": ua, "up_b": ub} for a, b, ua, ub in pairs]
    _run(AlignWorker, args, items, ("cloud_a", "cloud_b"), output, workers, ray_address, threads,
         batch_size, progress, "pairs")  # fmt: skip


@app.command("scene")
@request_options(SceneRequest)
def scene(
    inputs: list[str] = typer.Argument(
        ...,
        help="Depth images (.png, .npy), scene clouds or recordings (ROS bags: .bag, .db3, .mcap, "
        "a ROS 2 bag folder): files, folders (recursive), globs.",
    ),
    output: Path = typer.Option(..., "--output", "-o", help=OUTPUT_HELP),
    workers: int = typer.Option(1, min=1, help=WORKERS_HELP),
    ray_address: str | None = typer.Option(None, "--ray", help=RAY_HELP),
    model_dir: Path | None = scene_command.MODEL_DIR,
    intrinsics: str | None = scene_command.INTRINSICS,
    indices: bool = typer.Option(
        False,
        "--indices/--no-indices",
        help="Each object's point indices (thousands an object: off unless asked for).",
    ),
    topic: str | None = rec.TOPIC,
    camera_info: str | None = rec.CAMERA_INFO,
    every: int = rec.EVERY,
    start: float | None = rec.START,
    end: float | None = rec.END,
    threads: int | None = typer.Option(None, min=1, help=THREADS_HELP),
    batch_size: int = typer.Option(8, min=1, help="Scenes (recordings) per worker call."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
    request: SceneRequest = REQUEST,
) -> None:
    """Every object of every depth image or scene cloud, as `itnet scene --json` gives it: a row
    a file (a recording: a row a frame, with its topic and header), its objects in one column."""
    _require_ray()
    import dataclasses

    from itnet.commands.in_process import get_classifier
    from itnet.scale.workers import SceneWorker

    chosen = rec.selection(topic, camera_info, every, start, end)
    arguments = scene_command.scene_arguments(intrinsics, request)
    files = _scene_files(inputs)
    get_classifier(model_dir)  # exit 2 for a folder the workers could not name objects with
    args = {"model_dir": _dir(model_dir), "arguments": arguments, "indices": indices,
            "selection": dataclasses.asdict(chosen)}  # fmt: skip
    _run(SceneWorker, args, [{"file": f} for f in files], ("file",), output, workers,
         ray_address, threads, batch_size, progress, "scenes")  # fmt: skip


def _scene_files(inputs: list[str]) -> list[str]:
    """Depth images, clouds and recordings of ``inputs`` (a ROS 2 bag once, as its folder,
    however many storage files it has); exit 2 where there are none."""
    from itnet.cloud_io import SUFFIXES
    from itnet.recordings import is_recording
    from itnet.recordings.bag import RECORDING_SUFFIXES, bag_root
    from itnet.scale.inputs import InputError, expand_inputs
    from itnet.scene.inputs import IMAGE_SUFFIXES

    try:
        files = expand_inputs(inputs, IMAGE_SUFFIXES + SUFFIXES + RECORDING_SUFFIXES,
                              "depth images, clouds or recordings")  # fmt: skip
    except InputError as err:
        _fail(str(err))
    if any(is_recording(Path(f)) for f in files):
        rec.require_rosbags()
    return list(
        dict.fromkeys(str(bag_root(Path(f))) if is_recording(Path(f)) else f for f in files)
    )


def _dir(path: Path | None) -> str | None:
    return None if path is None else str(path.resolve())


def _run(worker: type, args: dict[str, Any], items: list[dict[str, str]], key: tuple[str, ...],
         output: Path, workers: int, address: str | None, threads: int | None, batch_size: int,
         progress: bool, what: str) -> None:  # fmt: skip
    from itnet.pose.runtime import ModelLoadError
    from itnet.scale.batch import run_batch, worker_threads
    from itnet.scale.table import BatchTable, OutputError

    try:
        table = BatchTable(output, key)
        stats = run_batch(worker, args, items, table, key, workers, address,
                          worker_threads(workers, threads, address), batch_size, progress)  # fmt: skip
    except (OutputError, ModelLoadError) as err:
        _fail(str(err))
    rate = f", {stats.steady_per_second:.1f} {what}/s steady" if stats.steady_per_second else ""
    typer.echo(
        f"{output}: {stats.rows} rows ({stats.done} new, {stats.skipped} already there, "
        f"{stats.errors} errors) in {stats.seconds:.1f} s{rate} with {workers} worker(s)",
        err=True,
    )
