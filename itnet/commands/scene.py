"""``itnet scene FILE...``: every object of a depth image or a scene cloud, its category and pose.

The options are ``SceneRequest``'s fields (shared with ``itnet batch scene``) and the depth
camera's intrinsics; ``scene_arguments`` turns them into ``find_objects``' keywords.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from itnet.commands import recordings as rec
from itnet.commands.request_options import REQUEST, request_options
from itnet.scene.request import SceneRequest
from itnet.scene.result import scene_row

FILES_HELP = (
    "Depth images (.png 16-bit, .npy), scene clouds (.ply .pcd .xyz .npy), or recordings: ROS 1 "
    "bags (.bag), ROS 2 bags (a folder, .db3, .mcap)"
)
INTRINSICS = typer.Option(
    None,
    help="The depth camera's 'fx,fy,cx,cy' in pixels, or a JSON file of them (fx/fy/cx/cy, "
    "ROS CameraInfo's K, or Open3D's intrinsic_matrix). Needed for depth images.",
)
MODEL_DIR = typer.Option(None, help="Folder of .onnx models (default: shipped).")


def scene_arguments(intrinsics: str | None, request: SceneRequest) -> dict[str, Any]:
    """The camera and the request as ``find_objects``' keywords (plain values, picklable), or a
    usage error (typer.BadParameter) for intrinsics that cannot be read."""
    from itnet.scene import SceneInputError, parse_intrinsics

    try:
        camera = None if intrinsics is None else parse_intrinsics(intrinsics)
    except SceneInputError as err:
        raise typer.BadParameter(str(err)) from None
    return {"intrinsics": camera, **request.arguments()}


@request_options(SceneRequest)
def scene(
    files: list[Path] = typer.Argument(..., help=FILES_HELP),
    intrinsics: str | None = INTRINSICS,
    model_dir: Path | None = MODEL_DIR,
    indices: bool = typer.Option(
        True, "--indices/--no-indices", help="With --json: each object's point indices."
    ),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per file, per line."),
    fmt: str = typer.Option(
        "text",
        "--format",
        help="text, json (as --json) or ros: a frame's vision_msgs/"
        "Detection3DArray as JSON, a line a frame (recordings).",
    ),
    topic: str | None = rec.TOPIC,
    camera_info: str | None = rec.CAMERA_INFO,
    every: int = rec.EVERY,
    start: float | None = rec.START,
    end: float | None = rec.END,
    output_bag: Path | None = typer.Option(
        None,
        help="A recording's answers written into this bag beside its topics (.bag: ROS 1; "
        "else a ROS 2 bag folder): Detection3DArray on /itnet/detections, PoseStamped on "
        "/itnet/poses.",
    ),
    rerun: Path | None = typer.Option(
        None, help="A Rerun log (.rrd) of every frame's points, boxes, axes and categories."
    ),
    rerun_viewer: bool = typer.Option(
        False, "--rerun-viewer", help="Send the Rerun log to a viewer it spawns."
    ),
    request: SceneRequest = REQUEST,
) -> None:
    """Find the objects standing on the floor of each scene (camera frame: x right, y down, z
    ahead, metres): category, probability, T_canonical_from_input, box, points. A recording's
    every frame is answered with its header. Bad files and frames are reported and skipped
    (exit 2)."""
    from itnet.recordings import is_recording
    from itnet.scene.posing import ModelLoadError, scene_catalog
    from itnet.scene.warm_up import warm_up

    arguments = scene_arguments(intrinsics, request)
    fmt = "json" if as_json else fmt
    if fmt not in rec.FORMATS:
        raise typer.BadParameter(f"--format must be one of {', '.join(rec.FORMATS)}, got {fmt!r}")
    chosen = rec.selection(topic, camera_info, every, start, end)
    if any(is_recording(path) for path in files):
        rec.require_rosbags()
    try:
        catalog = scene_catalog(model_dir)
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    warm_up(catalog)  # the first file's budget is not spent on one-time work
    outputs = rec.SceneOutputs(output_bag, rec.open_rerun(rerun, rerun_viewer))
    ok = True
    for path in files:
        if is_recording(path):
            ok &= rec.scene_recording(path, chosen, arguments, catalog, fmt, indices, outputs)
        else:
            ok &= scene_file(path, arguments, catalog, fmt, indices)
    if outputs.rerun is not None:
        outputs.rerun.close()
    if not ok:
        raise typer.Exit(2)


def scene_file(
    path: Path, arguments: dict[str, Any], catalog: Any, fmt: str, indices: bool
) -> bool:
    """Answer and print one depth image or scene cloud; False where it cannot be used."""
    import numpy as np

    from itnet.geometry import rotation_angle_deg
    from itnet.scene import SceneInputError, find_objects

    try:
        result = find_objects(path, catalog=catalog, **arguments)
    except SceneInputError as err:
        typer.echo(f"error: {path}: {err}", err=True)
        return False
    if fmt == "ros":  # a file has no header: stamp 0, no frame_id
        from itnet.recordings import detection_array

        header = {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
        typer.echo(json.dumps(detection_array(header, [o.as_dict(False) for o in result.objects])))
        return True
    if fmt == "json":
        typer.echo(json.dumps(scene_row(path, result, indices)))
        return True
    typer.echo(f"{path}: {len(result.objects)} object(s) in {result.elapsed_ms:.0f} ms")
    for obj in result.objects:
        centre = np.round(obj.box.center, 2).tolist()
        pose = (
            "no pose (" + str(obj.no_pose) + ")"
            if obj.pose is None
            else f"rotation {float(rotation_angle_deg(obj.pose[:3, :3])):.1f} deg"
        )
        name = obj.category or f"unknown: {obj.unknown}"
        typer.echo(f"  {name} ({obj.probability:.2f}), {len(obj.indices)} points, "
                   f"box centre {centre} m, {pose}")  # fmt: skip
    return True
