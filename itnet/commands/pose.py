"""``itnet pose FILE...``: the canonical pose of each cloud file, in-process (onnxruntime)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from itnet.commands import recordings as rec
from itnet.commands.request_options import REQUEST, request_options
from itnet.pose.files import pose_row
from itnet.pose.request import PoseRequest

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from itnet.pose.loop import AnytimeRun


@request_options(PoseRequest)
def pose(
    files: list[Path] = typer.Argument(
        ...,
        help="Cloud files (.ply .pcd .xyz .pts .txt .npy), or recordings (ROS bags: .bag, "
        "a ROS 2 folder, .db3, .mcap) of an object's sensor_msgs/PointCloud2",
    ),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line."),
    topic: str | None = typer.Option(
        None, help="A bag's sensor_msgs/PointCloud2 topic (default: its only one)."
    ),
    every: int = rec.EVERY,
    start_s: float | None = rec.START,
    end_s: float | None = rec.END,
    request: PoseRequest = REQUEST,
) -> None:
    """Estimate T_canonical_from_input for each file. Bad files are reported and skipped (exit 2)."""
    from itnet.commands.in_process import get_catalog, get_classifier, get_model
    from itnet.recordings import is_recording

    chosen = rec.selection(topic, None, every, start_s, end_s)
    if any(is_recording(path) for path in files):
        rec.require_rosbags()
    catalog = get_catalog(model_dir)
    if catalog.is_auto(request.model):
        get_classifier(model_dir)  # a folder without a classifier: one clear error, exit 2
    else:
        get_model(request.model, model_dir)  # an unknown name: one clear error, exit 2

    def start(cloud: NDArray[np.float64]) -> AnytimeRun:
        return catalog.start(cloud, request)

    failed = False
    for path in files:
        if is_recording(path):
            failed |= not rec.pose_recording(path, chosen, start, as_json)
        else:
            failed |= not _pose_file(path, start, as_json)
    if failed:
        raise typer.Exit(2)


def _pose_file(path: Path, start: Callable[[NDArray[np.float64]], AnytimeRun],
               as_json: bool) -> bool:  # fmt: skip
    """Pose one cloud file and print its row; False (after saying why) where it cannot be used."""
    from itnet.cloud_io import CloudReadError
    from itnet.pose.errors import PoseError

    try:
        result = pose_row(path, start)
    except (CloudReadError, PoseError) as err:
        said = str(err) if str(err).startswith(str(path)) else f"{path}: {err}"
        typer.echo(f"error: {said}", err=True)
        return False
    typer.echo(json.dumps(result) if as_json else f"{path}: {summary(result)}")
    return True


def summary(result: dict[str, Any]) -> str:
    """A pose row as one line of text: category, rotation, translation, iterations, finishing."""
    import numpy as np

    from itnet.geometry import rotation_angle_deg

    t = np.asarray(result["T_canonical_from_input"])
    seen = (
        f"{result['category']} ({result['category_probability']:.2f}"
        f"{', unsure' if result['unsure'] else ''}, model {result['model']}), "
        if "category" in result
        else ""
    )
    finished = "".join(
        f", {said}"
        for key, said in (
            ("verified", "verified"),
            ("mirror", "mirror-finished"),
            ("centre", "centre-corrected"),
            ("up", "held upright"),
        )
        if result.get(key)
    )
    return (
        f"{seen}rotation {float(rotation_angle_deg(t[:3, :3])):.1f} deg, translation "
        f"[{t[0, 3]:.4g}, {t[1, 3]:.4g}, {t[2, 3]:.4g}], {result['iterations']} iterations "
        f"in {result['elapsed_ms']:.1f} ms (stopped by {result['stopped_by']}{finished})"
    )
