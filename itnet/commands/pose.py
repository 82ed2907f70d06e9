"""``itnet pose FILE...``: the canonical pose of each cloud file, in-process (onnxruntime)."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def pose(
    files: list[Path] = typer.Argument(..., help="Cloud files: .ply .pcd .xyz .pts .txt .npy"),
    model: str = typer.Option("chair", help="Model name (a shipped one, or one in --model-dir)."),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    budget_ms: float = typer.Option(1000.0, help="Time budget per file, in milliseconds."),
    max_iterations: int | None = typer.Option(None, help="Iteration cap (default: the model's)."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line."),
) -> None:
    """Estimate T_canonical_from_input for each file. Bad files are reported and skipped (exit 2)."""
    from itnet.cloud_io import CloudReadError, read_cloud
    from itnet.geometry import rotation_angle_deg
    from itnet.service.engine import AnytimeRun, BadCloudError
    from itnet.service.models_in_process import get_model

    loaded = get_model(model, model_dir)
    failed = False
    for path in files:
        try:
            run = AnytimeRun(
                loaded, read_cloud(path), budget_ms=budget_ms, max_iterations=max_iterations
            )
        except (CloudReadError, BadCloudError) as err:
            typer.echo(
                f"error: {path}: {err}" if not str(err).startswith(str(path)) else f"error: {err}",
                err=True,
            )
            failed = True
            continue
        run.run_to_end()
        result = {"file": str(path), **run.result()}
        if as_json:
            typer.echo(json.dumps(result))
        else:
            t = run.last.pose
            typer.echo(
                f"{path}: rotation {float(rotation_angle_deg(t[:3, :3])):.1f} deg, translation "
                f"[{t[0, 3]:.4g}, {t[1, 3]:.4g}, {t[2, 3]:.4g}], {result['iterations']} iterations "
                f"in {result['elapsed_ms']:.1f} ms (stopped by {result['stopped_by']})"
            )
    if failed:
        raise typer.Exit(2)
