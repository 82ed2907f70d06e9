"""``itnet scene FILE...``: every object of a depth image or a scene cloud, its category and pose.

The options that say how a scene is read and finished are declared once here and shared with
``itnet batch scene``; ``scene_arguments`` checks them and turns them into ``find_objects``'
keywords, and ``scene_row`` is the JSON row both print.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from itnet.commands import check_xyz
from itnet.commands import recordings as rec
from itnet.scene.pipeline import DEFAULT_BUDGET_MS, up_direction

if TYPE_CHECKING:
    from itnet.scene import SceneResult

FILES_HELP = (
    "Depth images (.png 16-bit, .npy), scene clouds (.ply .pcd .xyz .npy), or recordings: ROS 1 "
    "bags (.bag), ROS 2 bags (a folder, .db3, .mcap)"
)
INTRINSICS = typer.Option(
    None,
    help="The depth camera's 'fx,fy,cx,cy' in pixels, or a JSON file of them (fx/fy/cx/cy, "
    "ROS CameraInfo's K, or Open3D's intrinsic_matrix). Needed for depth images.",
)
DEPTH_SCALE = typer.Option(
    None,
    help="Depth units per metre of a depth image (default: 1000 for 16-bit images, "
    "millimetres; 1 for float .npy, metres).",
)
BUDGET_MS = typer.Option(
    DEFAULT_BUDGET_MS, help="Time budget per scene in ms, shared among its objects."
)
MODEL_DIR = typer.Option(None, help="Folder of .onnx models (default: shipped).")
FLOOR_CENTRE = typer.Option(
    True, "--floor-centre/--no-floor-centre", help="Each object's height from the floor."
)
ALONG_FLOOR = typer.Option(
    True,
    "--along-floor/--no-along-floor",
    help="Each object's place along the floor by its pose model's scene correction.",
)
RECHECK = typer.Option(
    True,
    "--recheck/--no-recheck",
    help="A pose its category's verifier doubts weighed against the second category's.",
)
SCENE_CLASSIFIER = typer.Option(
    True,
    "--scene-classifier/--no-scene-classifier",
    help="Name each object by its shape on the floor too (else the classifier and height).",
)
SPLIT_TOUCHING = typer.Option(
    True,
    "--split-touching/--no-split-touching",
    help="Cut a cluster where the cut judge finds two objects standing against each other.",
)
UNKNOWN = typer.Option(
    True,
    "--unknown/--no-unknown",
    help="A cluster no category fits answered as unknown (category null), not named.",
)
NAMED_SPLIT = typer.Option(
    True,
    "--named-split/--no-named-split",
    help="A cluster too large for its category parted where the recognition finds two objects.",
)
UP = typer.Option(
    None,
    help="Which way is up in the camera's frame, 'x,y,z' (e.g. from an IMU's gravity); the "
    "floor is searched within 45 degrees of it (default 0,-1,0: a camera held about level).",
    callback=check_xyz,
)


def scene_arguments(
    intrinsics: str | None,
    depth_scale: float | None,
    budget_ms: float,
    up: list[float] | None,
    floor_centre: bool = True,
    along_floor: bool = True,
    recheck: bool = True,
    scene_classifier: bool = True,
    split_touching: bool = True,
    unknown: bool = True,
    named_split: bool = True,
) -> dict[str, Any]:
    """The scene options as ``find_objects``' keywords (plain values, picklable), or a usage
    error (typer.BadParameter) saying which one is wrong."""
    import numpy as np

    from itnet.scene import SceneFinishing, SceneInputError, parse_intrinsics
    from itnet.scene.segment import SegmentOptions

    if not 0 < budget_ms <= 60_000:
        raise typer.BadParameter(f"--budget-ms must be in (0, 60000], got {budget_ms:g}")
    if up is not None:
        try:
            up_direction(np.asarray(up, dtype=np.float64))
        except ValueError as err:
            raise typer.BadParameter(f"--up: {err}") from None
    try:
        camera = None if intrinsics is None else parse_intrinsics(intrinsics)
    except SceneInputError as err:
        raise typer.BadParameter(str(err)) from None
    return {
        "intrinsics": camera,
        "budget_ms": budget_ms,
        "depth_scale": depth_scale,
        "finishing": SceneFinishing(
            floor_centre, along_floor, recheck, unknown=unknown, named_split=named_split
        ),
        "scene_classifier": scene_classifier,
        "options": SegmentOptions(split_touching=split_touching),
        **({} if up is None else {"expected_up": tuple(up)}),
    }


def scene_row(path: Path | str, result: SceneResult, indices: bool) -> dict[str, Any]:
    """What ``itnet scene --json`` prints for a file: ``file`` and the result's JSON form."""
    return {"file": str(path), **result.as_dict(indices)}


def scene(
    files: list[Path] = typer.Argument(..., help=FILES_HELP),
    intrinsics: str | None = INTRINSICS,
    depth_scale: float | None = DEPTH_SCALE,
    budget_ms: float = BUDGET_MS,
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
    floor_centre: bool = FLOOR_CENTRE,
    along_floor: bool = ALONG_FLOOR,
    recheck: bool = RECHECK,
    scene_classifier: bool = SCENE_CLASSIFIER,
    split_touching: bool = SPLIT_TOUCHING,
    unknown: bool = UNKNOWN,
    named_split: bool = NAMED_SPLIT,
    up: str | None = UP,
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
) -> None:
    """Find the objects standing on the floor of each scene (camera frame: x right, y down, z
    ahead, metres): category, probability, T_canonical_from_input, box, points. A recording's
    every frame is answered with its header. Bad files and frames are reported and skipped
    (exit 2)."""
    from itnet.recordings import is_recording
    from itnet.scene.posing import ModelLoadError, scene_catalog
    from itnet.scene.warm_up import warm_up

    arguments = scene_arguments(intrinsics, depth_scale, budget_ms, up, floor_centre,  # type: ignore[arg-type]
                                along_floor, recheck, scene_classifier, split_touching, unknown,
                                named_split)  # fmt: skip
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
