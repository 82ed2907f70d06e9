"""``itnet verifier-train`` and ``itnet verifier-export``: a category's learned verifier, which
tells a pose model's right runs from its wrong ones (``model/verifier.py``)."""

from __future__ import annotations

from pathlib import Path

import typer


def verifier_train(
    pose_model: Path = typer.Option(
        ..., help="The exported pose model (.onnx) whose runs it learns from."
    ),
    out: Path = typer.Option(..., help="Run folder: verifier.pt, config.json, log.jsonl."),
    category: str | None = typer.Option(None, help="Default: the pose model's card's."),
    steps: int = typer.Option(4000, min=1),
    batch: int = typer.Option(128, min=2),
    views: int = typer.Option(8, min=1, help="Scans of each training shape, per view rule."),
    scanners: str = typer.Option(
        "paper,occluded,surface",
        help="View rules, comma-separated: RULE, RULE+SENSOR (occluded+kinect_v2: by a depth "
        "camera, at the category's real sizes), RULE+SENSOR+crop (cut out of a room), +clutter.",
    ),
    ensemble: int = typer.Option(8, min=1, max=16, help="Runs per scan, from turned starts."),
    synthetic: float = typer.Option(
        0.5, min=0.0, max=1.0, help="Share of each batch that is the truth knocked off."
    ),
    up_error_deg: float | None = typer.Option(
        None,
        min=0.0,
        max=45.0,
        help="Hold the runs upright, each scan's up given this far off (degrees). Default: 2 "
        "where the pose model requires up, else free runs.",
    ),
    threads: int = typer.Option(2, min=1),
    data: Path = typer.Option(Path("../shared/data/modelnet10"), help="ModelNet-style root."),
    cache: Path = typer.Option(Path("cache"), help="Cache of shapes, scans and runs."),
) -> None:
    """Run the pose model on the category's training shapes as the engine fuses runs, and
    train a PointNet to tell its right runs (< 15 degrees) from its wrong ones (> 25) by how
    the cloud looks where each run puts it. The validation shapes are not touched."""
    from itnet.commands.request_options import build_request
    from itnet.model.verifier import VerifierConfig, train_verifier
    from itnet.pose.runtime import ModelLoadError, load_model

    try:
        card = load_model(pose_model, warm_up=False).card
    except ModelLoadError as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from None
    config = build_request(VerifierConfig, dict(
        category=category or card.category, pose_model=pose_model, steps=steps, batch=batch,
        views=views, scanners=[s for s in scanners.split(",") if s], ensemble=ensemble,
        synthetic=synthetic, up_error_deg=up_error_deg, threads=threads, data=data, cache=cache,
    ))  # fmt: skip
    path = train_verifier(config, out, log=lambda line: typer.echo(line, err=True))
    typer.echo(str(path))


def verifier_export(
    checkpoint: Path = typer.Argument(..., help="verifier.pt of `itnet verifier-train`."),
    out: Path = typer.Option(..., help="The .onnx to write (beside the pose models it serves)."),
    name: str | None = typer.Option(None, help="Default: CATEGORY-verifier."),
    evaluation: str = typer.Option("", help="What it was measured to do, for the card."),
) -> None:
    """Export a verifier to ONNX with its card (kind 'verifier'). The service loads it beside
    the pose models of its category, and their fused runs' ``verify`` then anchors on the run
    it finds likeliest instead of running the network's probes."""
    from itnet.export.verifier_export import export_verifier
    from itnet.model.verifier import load_verifier
    from itnet.model_card import VerifierCard

    net, config = load_verifier(checkpoint)
    card = VerifierCard(
        name=name or f"{config.category}-verifier", category=config.category,
        points=config.points, trained_on=config.pose_model.name, evaluation=evaluation,
        training=config.model_dump(mode="json"),
    )  # fmt: skip
    typer.echo(str(export_verifier(net, card, out)))
