"""``itnet pose FILE...``: the canonical pose of each cloud file, in-process (onnxruntime)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from itnet.commands import UNITS_HELP, check_units, check_xyz

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from itnet.service.engine import AnytimeRun


def pose(
    files: list[Path] = typer.Argument(..., help="Cloud files: .ply .pcd .xyz .pts .txt .npy"),
    model: str = typer.Option(
        "chair",
        help="Model name (a shipped one, or one in --model-dir); 'auto': classify each cloud, "
        "then use its category's model.",
    ),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    budget_ms: float = typer.Option(1000.0, help="Time budget per file, in milliseconds."),
    max_iterations: int | None = typer.Option(None, help="Iteration cap (default: the model's)."),
    ensemble: int | None = typer.Option(
        None,
        min=1,
        max=16,
        help="Accuracy mode: K runs from starts turned 360/K degrees about the cloud's z axis, "
        "each on its own random subset, fused robustly after every iteration; a step costs about "
        "K times as much (still within --budget-ms). Default: the model's recommended count "
        "(`itnet models`; 1 for most), halved until its iterations fit --budget-ms.",
    ),
    mirror: bool | None = typer.Option(
        None,
        "--mirror/--no-mirror",
        help="Finish the final pose by the category's mirror symmetries (a few ms, "
        "within --budget-ms). Default: for a single run, where the model's card declares it "
        "(`itnet models`).",
    ),
    verify: bool | None = typer.Option(
        None,
        "--verify/--no-verify",
        help="With --ensemble: fuse the runs around the one that sits most firmly in its basin "
        "(each knocked off by four 30-degree turns, 5 steps back; about twice the runs' steps, "
        "within --budget-ms). Default: where the model's card says so (`itnet models --json`: "
        "verify_fused).",
    ),
    recheck: bool | None = typer.Option(
        None,
        "--recheck/--no-recheck",
        help="A single run the model's learned verifier doubts is rechecked by a few runs from "
        "turned starts (within --budget-ms), and the likeliest answer kept. Default: where the "
        "model's card says so (`itnet models --json`: recheck_runs).",
    ),
    centre: bool | None = typer.Option(
        None,
        "--centre/--no-centre",
        help="Finish the final pose's object centre by the model's centre correction (a fraction "
        "of a ms). Default: where the model's card has one (`itnet models`).",
    ),
    viewpoint: str | None = typer.Option(
        None,
        help="Where the sensor was, 'x,y,z' in the cloud's frame and units ('0,0,0' for a depth "
        "camera's cloud in its own frame): the centre correction then also goes by the "
        "direction toward it, where the model has that correction.",
        callback=check_xyz,
    ),
    up: str | None = typer.Option(
        None,
        help="Which way is up in the cloud, 'x,y,z' (against gravity: an IMU's, or a floor's "
        "normal; '0,-1,0' for a camera whose image y points down, held level): the pose is held "
        "upright and only its turn about up and its position are estimated.",
        callback=check_xyz,
    ),
    units: str | None = typer.Option(None, help=UNITS_HELP, callback=check_units),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line."),
) -> None:
    """Estimate T_canonical_from_input for each file. Bad files are reported and skipped (exit 2)."""
    import numpy as np

    from itnet.cloud_io import CloudReadError
    from itnet.geometry import rotation_angle_deg
    from itnet.service.engine import AnytimeRun, BadCloudError
    from itnet.service.errors import ServiceError
    from itnet.service.models_in_process import all_models, get_classifier, get_model
    from itnet.service.recognition import AUTO, auto_run

    auto = model == AUTO and AUTO not in all_models(model_dir)
    classifier = get_classifier(model_dir) if auto else None
    loaded = None if auto else get_model(model, model_dir)

    def start(cloud: NDArray[np.float64]) -> AnytimeRun:
        if loaded is None:  # the classification counts against the budget
            return auto_run(
                classifier, all_models(model_dir), cloud, budget_ms, max_iterations,
                ensemble=ensemble, units=units, mirror=mirror, centre=centre, viewpoint=viewpoint,
                up=up, verify=verify, recheck=recheck,
            )  # fmt: skip
        return AnytimeRun(
            loaded, cloud, budget_ms=budget_ms, max_iterations=max_iterations, ensemble=ensemble,
            mirror=mirror, centre=centre, viewpoint=viewpoint, up=up, verify=verify,
            recheck=recheck,
        )  # fmt: skip

    failed = False
    for path in files:
        try:
            result = pose_row(path, start)
        except ServiceError as err:
            typer.echo(f"error: {path}: {err.detail}", err=True)
            failed = True
            continue
        except (CloudReadError, BadCloudError) as err:
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
