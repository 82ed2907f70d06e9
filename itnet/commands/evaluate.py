"""``itnet eval``: the anytime accuracy curve on the test split, with a plot."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def evaluate(
    checkpoint: Path | None = typer.Option(None, help="Torch checkpoint (.pt) to evaluate."),
    onnx: Path | None = typer.Option(None, help="Or an exported .onnx step, run by onnxruntime."),
    data: Path = typer.Option(Path("../shared/data/modelnet10"), help="Dataset root."),
    category: str | None = typer.Option(
        None,
        help="Category of the test split (default: the model's; required for a checkpoint "
        "trained on several categories).",
    ),
    frame: str = typer.Option("modelnet"),
    views: int = typer.Option(5, help="Random views per test object."),
    iterations: int = typer.Option(20, help="Evaluate iterations 0..N."),
    points: int | None = typer.Option(
        None,
        help="Points each cloud is subsampled to (default: as the runtime, the model card's "
        "count; for a checkpoint, its training count).",
    ),
    seed: int = typer.Option(2024, help="Seed of the test views."),
    scanner: str = typer.Option(
        "occluded",
        help="Test views: 'occluded' (z-buffer with the 3x3 occlusion test, the product's "
        "benchmark), 'paper' (the paper's nearest point per pixel) or 'surface' (each point a disc, "
        "as a camera sees a mesh), or RULE+SENSOR (occluded+kinect_v2: by that depth camera, at "
        "the category's real sizes); see model/scanner.py.",
    ),
    out: Path = typer.Option(Path("runs/eval"), help="Folder for report.json and anytime.png."),
    dump_scans: Path | None = typer.Option(
        None, help="Also write the test scans as .npy files plus labels.json (for `itnet pose`)."
    ),
    check_orientation: bool = typer.Option(
        True, help="Turn back or drop test shapes turned about up, as training does."
    ),
    cache: Path = typer.Option(Path("cache")),
    up: float | None = typer.Option(
        None,
        min=0.0,
        metavar="ERROR_DEG",
        help="Give each run its scan's up direction, tilted ERROR_DEG degrees from the truth (a "
        "gravity sensor's error), and hold it upright as the service does. Default: none, or 2 "
        "for a model whose card requires up.",
    ),
) -> None:
    """Accuracy at (10°, 0.1 radius) for every iteration 0..N, median errors, CDF plot."""

    import numpy as np

    from itnet.model.categories import model_category
    from itnet.model.category_set import test_scans
    from itnet.model.evaluate import anytime_poses, report
    from itnet.model.plots import plot_anytime
    from itnet.model.scanner import named_views

    batch = 50  # clouds per network call
    if (checkpoint is None) == (onnx is None):
        raise typer.BadParameter("give exactly one of --checkpoint or --onnx")
    if checkpoint is not None:
        from itnet.model.evaluate import torch_step
        from itnet.model.train import load_checkpoint

        net, state = load_checkpoint(checkpoint)
        step, trained = torch_step(net), state["config"]["iterations"]
        points = int(state["config"]["points"]) if points is None else points
        trained_on, symmetry = state["config"]["category"], state["config"].get("symmetry")
    else:
        from itnet.pose.runtime import load_model

        model = load_model(onnx, warm_up=False)
        step, trained = (lambda x, p: model.step(x, p)[0]), model.card.trained_iterations
        # int8 graphs quantise activations with one scale per call: batched clouds would
        # influence each other. The runtime steps one cloud at a time, and so does this.
        batch = 1 if model.card.precision == "int8" else batch
        points = model.card.points if points is None else points
        trained_on, symmetry = model.card.category, model.card.symmetry
        if up is None and model.card.requires_up:  # served only with up: measured only so
            from itnet.upright import UPRIGHT_EVAL_DEG

            up = UPRIGHT_EVAL_DEG
    try:
        cat = model_category(category, trained_on, symmetry)
    except ValueError as err:
        raise typer.BadParameter(str(err)) from None
    try:
        config = named_views(scanner, cat.name)
    except ValueError as err:
        raise typer.BadParameter(f"--scanner: {err}") from None
    scans, orientation = test_scans(data, cat, views, seed, config, cache, frame, check_orientation)
    ups, free = None, 0
    if up is not None:  # each scan's true up, tilted as a gravity sensor's would be
        from itnet.upright import sensed_ups

        ups = sensed_ups(scans.poses, up, np.random.default_rng(seed + 1))
        free = 0 if onnx is None else model.card.up_free_steps
    poses = anytime_poses(step, scans, iterations, points, batch=batch, ups=ups, free_steps=free)
    rep, rot, trans = report(poses, scans, cat.symmetry)
    out.mkdir(parents=True, exist_ok=True)
    summary = {
        "source": str(checkpoint or onnx),
        "category": cat.name,
        "symmetry": cat.symmetry,
        "orientation": orientation,
        "views": views,
        "scanner": scanner,
        "seed": seed,
        "points": points,
        **({} if up is None else {"up_error_deg": up, "up_free_steps": free}),
        **rep.model_dump(),
    }
    (out / "report.json").write_text(json.dumps(summary, indent=1))
    np.savez_compressed(out / "poses.npz", poses=poses, truth=scans.poses, radii=scans.radii)
    plot_anytime(
        rep,
        rot,
        trans,
        trained,
        out / "anytime.png",
        f"{cat.name} ({cat.symmetry}): {rep.scans} partial scans ({scanner} views) of held-out objects",
    )
    if dump_scans is not None:
        dump_scans.mkdir(parents=True, exist_ok=True)
        labels = {}
        for i, cloud in enumerate(scans.clouds):
            name = f"scan_{i:04d}.npy"
            np.save(dump_scans / name, cloud.astype(np.float32))
            labels[name] = {
                "T_canonical_from_input": scans.poses[i].tolist(),
                "radius": float(scans.radii[i]),
                "object": scans.names[i],
            }
        (dump_scans / "labels.json").write_text(json.dumps(labels))
    typer.echo("iteration  accuracy  rot<10°  trans<0.1  median rot°  median trans")
    for k in rep.iterations:
        typer.echo(
            f"{k:9d}  {rep.accuracy[k]:8.3f}  {rep.rotation_accuracy[k]:7.3f}  "
            f"{rep.translation_accuracy[k]:9.3f}  {rep.median_rotation_deg[k]:11.2f}  "
            f"{rep.median_translation[k]:12.4f}"
        )
    typer.echo(
        f"{rep.scans} scans of {len(set(scans.names))} test objects ({orientation}); "
        f"wrote {out / 'report.json'} and {out / 'anytime.png'}"
    )
