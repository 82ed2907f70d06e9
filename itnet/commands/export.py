"""``itnet export``: a trained checkpoint -> one ONNX step graph with its model card."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from itnet.commands import ensemble_evaluation, parse_mirror_planes


def export(
    checkpoint: Path = typer.Argument(..., help="Torch checkpoint (best.pt of a run)."),
    out: Path | None = typer.Option(
        None, help="Output .onnx file (default: itnet/models/<name>.onnx)."
    ),
    name: str | None = typer.Option(
        None, help="Model name used in requests (default: the category)."
    ),
    category: str | None = typer.Option(
        None,
        help="Category the model answers for (default: the one it was trained on; required for "
        "a network trained on several: export it once per category).",
    ),
    points: int | None = typer.Option(
        None,
        help="Points the runtime subsamples a larger cloud to (default: the count the model was "
        "trained on: the density it knows, and the cheapest step).",
    ),
    recommended_iterations: int = typer.Option(10, help="Default iteration cap of the runtime."),
    recommended_ensemble: int = typer.Option(
        1,
        min=1,
        max=16,
        help="Runs fused per estimate when a request does not say (needs "
        "--ensemble-report above 1).",
    ),
    mirror_planes: str | None = typer.Option(
        None,
        help="Canonical planes the category is mirror-symmetric about, comma-separated: 'x' "
        "(x = 0, left-right), 'z' (z = 0, front-back), or 'none'; the runtime finishes poses by "
        "them (itnet.mirror). Default: measured for ModelNet10's classes (`python -m "
        "itnet.model.categories`), none for your own category.",
    ),
    report: Path | None = typer.Option(None, help="report.json of `itnet eval` to record."),
    ensemble_report: Path | None = typer.Option(
        None, help="JSON of `python -m benchmarks.bench_ensemble` measuring that ensemble."
    ),
    version: str = typer.Option("1"),
    int8: bool = typer.Option(
        False, "--int8", help="Quantise the per-point layers to int8 (1.3x faster on 2 cores)."
    ),
) -> None:
    """Export, then check the graph against torch on random clouds (max abs difference)."""
    import tempfile

    import numpy as np
    import torch

    from itnet.export.onnx_export import export_step
    from itnet.export.quantize import quantize_point_layers
    from itnet.model.categories import model_category
    from itnet.model.train import load_checkpoint
    from itnet.model_card import ModelCard, describe_anytime
    from itnet.pose.runtime import load_model

    net, state = load_checkpoint(checkpoint)
    config = state["config"]
    trained_on = str(config["category"])
    try:
        cat = model_category(category, trained_on, config.get("symmetry"))
    except ValueError as err:
        raise typer.BadParameter(str(err)) from None
    points = int(config["points"]) if points is None else points
    accuracy, evaluation = {}, ""
    if report is not None:
        accuracy, evaluation = describe_anytime(json.loads(report.read_text()))
    ensemble_text = ensemble_evaluation(recommended_ensemble, ensemble_report)
    name = name or cat.name  # a mug model is served as 'mug', not 'chair'
    out = out or Path("itnet/models") / f"{name}.onnx"
    card = ModelCard(
        name=name,
        category=cat.name,
        symmetry=cat.symmetry,
        mirror_planes=parse_mirror_planes(mirror_planes, cat.mirror_planes),
        version=version,
        points=points,
        trained_points=config["points"],
        trained_iterations=config["iterations"],
        recommended_iterations=recommended_iterations,
        recommended_ensemble=recommended_ensemble,
        accuracy=accuracy,
        evaluation=evaluation,
        ensemble_evaluation=ensemble_text,
        # an upright network knows only levelled views: served to requests that give up
        requires_up=config.get("upright") is not None,
        training={
            "steps": state["step"],
            "batch": config["batch"],
            "lr": config["lr"],
            "decay_every": config["decay_every"],
            "bf16": config["bf16"],
            "validation": state["metrics"].get("val_accuracy"),
            "categories": trained_on,
            **({"upright": config["upright"]} if config.get("upright") is not None else {}),
        },
    )
    if int8:
        with tempfile.TemporaryDirectory() as tmp:
            quantize_point_layers(export_step(net, card, Path(tmp) / "float32.onnx"), out)
    else:
        export_step(net, card, out)
    model = load_model(out, warm_up=False)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4, points, 3)).astype(np.float32)
    pose = np.tile(np.eye(4, dtype=np.float32), (4, 1, 1))
    with torch.no_grad():
        expected = net.step(torch.from_numpy(x), torch.from_numpy(pose))[0].numpy()
    diff = float(np.abs(model.step(x, pose)[0] - expected).max())
    typer.echo(
        f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB); ONNX vs torch max |diff| {diff:.2e}"
    )
