"""``itnet pose FILE...``: the canonical pose of each cloud file, in-process (onnxruntime)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from itnet.commands import UNITS_HELP, check_units, check_xyz, from_options
from itnet.commands import recordings as rec
from itnet.pose.request import field_help

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from itnet.pose.loop import AnytimeRun
    from itnet.pose.request import PoseRequest


def pose(
    files: list[Path] = typer.Argument(
        ...,
        help="Cloud files (.ply .pcd .xyz .pts .txt .npy), or recordings (ROS bags: .bag, "
        "a ROS 2 folder, .db3, .mcap) of an object's sensor_msgs/PointCloud2",
    ),
    model: str = typer.Option(
        "chair",
        help="Model name (a shipped one, or one in --model-dir); 'auto': classify each cloud, "
        "then use its category's model.",
    ),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    budget_ms: float = typer.Option(1000.0, help="Time budget per file, in milliseconds."),
    max_iterations: int | None = typer.Option(None, help=field_help("max_iterations")),
    ensemble: int | None = typer.Option(None, min=1, max=16, help=field_help("ensemble")),
    mirror: bool | None = typer.Option(None, "--mirror/--no-mirror", help=field_help("mirror")),
    verify: bool | None = typer.Option(None, "--verify/--no-verify", help=field_help("verify")),
    recheck: bool | None = typer.Option(None, "--recheck/--no-recheck", help=field_help("recheck")),
    centre: bool | None = typer.Option(None, "--centre/--no-centre", help=field_help("centre")),
    viewpoint: str | None = typer.Option(None, help=field_help("viewpoint"), callback=check_xyz),
    up: str | None = typer.Option(None, help=field_help("up"), callback=check_xyz),
    units: str | None = typer.Option(None, help=UNITS_HELP, callback=check_units),
    runs: bool = typer.Option(False, "--runs", help=field_help("runs")),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line."),
    topic: str | None = typer.Option(
        None, help="A bag's sensor_msgs/PointCloud2 topic (default: its only one)."
    ),
    every: int = rec.EVERY,
    start_s: float | None = rec.START,
    end_s: float | None = rec.END,
) -> None:
    """Estimate T_canonical_from_input for each file. Bad files are reported and skipped (exit 2)."""
    import numpy as np

    from itnet.cloud_io import CloudReadError
    from itnet.commands.in_process import get_catalog, get_classifier, get_model
    from itnet.geometry import rotation_angle_deg
    from itnet.pose.errors import PoseError
    from itnet.recordings import is_recording

    chosen = rec.selection(topic, None, every, start_s, end_s)
    if any(is_recording(path) for path in files):
        rec.require_rosbags()
    catalog = get_catalog(model_dir)
    if catalog.is_auto(model):
        get_classifier(model_dir)  # a folder without a classifier: one clear error, exit 2
    else:
        get_model(model, model_dir)  # an unknown name: one clear error, exit 2
    request = request_from_options(
        budget_ms=budget_ms, max_iterations=max_iterations, model=model, ensemble=ensemble,
        mirror=mirror, verify=verify, recheck=recheck, centre=centre, viewpoint=viewpoint, up=up,
        units=units, runs=runs,
    )  # fmt: skip

    def start(cloud: NDArray[np.float64]) -> AnytimeRun:
        return catalog.start(cloud, request)

    failed = False
    for path in files:
        if is_recording(path):
            failed |= not rec.pose_recording(path, chosen, start, as_json)
            continue
        try:
            result = pose_row(path, start)
        except (CloudReadError, PoseError) as err:
            typer.echo(
                f"error: {path}: {err}" if not str(err).startswith(str(path)) else f"error: {err}",
                err=True,
            )
            failed = True
            continue
        if as_json:
            typer.echo(json.dumps(result))
        else:
            t = np.asarray(result["T_canonical_from_input"])
            seen = (
                f"{result['category']} ({result['category_probability']:.2f}"
                f"{', unsure' if result['unsure'] else ''}, model {result['model']}), "
                if "category" in result
                else ""
            )
            typer.echo(
                f"{path}: {seen}rotation {float(rotation_angle_deg(t[:3, :3])):.1f} deg, translation "
                f"[{t[0, 3]:.4g}, {t[1, 3]:.4g}, {t[2, 3]:.4g}], {result['iterations']} iterations "
                f"in {result['elapsed_ms']:.1f} ms (stopped by {result['stopped_by']}"
                f"{', verified' if result.get('verified') else ''}"
                f"{', mirror-finished' if result.get('mirror') else ''}"
                f"{', centre-corrected' if result.get('centre') else ''}"
                f"{', held upright' if result.get('up') else ''})"
            )
    if failed:
        raise typer.Exit(2)


def pose_row(path: Path, start: Callable[[NDArray[np.float64]], AnytimeRun]) -> dict[str, Any]:
    """One cloud file -> the row that ``itnet pose --json`` prints and ``itnet batch pose``
    writes: file, the pose fields, iterations, stopped_by, elapsed_ms, model. ``start`` sets up
    the run on the cloud (N, 3). Raises CloudReadError or BadCloudError (a file or cloud that
    cannot be used), or what ``start`` raises."""
    from itnet.cloud_io import read_cloud

    run = start(read_cloud(path))
    run.run_to_end()
    return {"file": str(path), **run.result()}


def request_from_options(**options: Any) -> PoseRequest:
    """The CLI's options -> PoseRequest (``itnet.commands.from_options``)."""
    from itnet.pose.request import PoseRequest

    return from_options(PoseRequest, **options)
