"""``itnet eval`` as a function: a checkpoint or an exported model run on a category's fixed test
views for iterations 0..N, measured at (10 deg, 0.1 radius), written as report.json, poses.npz
and the anytime plot (and, where asked, the scans themselves for ``itnet pose``).

    report = evaluate_model(EvalOptions(checkpoint=Path("runs/chair/best.pt"), views=2))
    report.anytime.accuracy[-1], report.report      # 0.71, runs/eval/report.json
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from itnet.model.categories import model_category
from itnet.model.category_set import test_scans
from itnet.model.data import ScanSet
from itnet.model.eval_config import EvalOptions
from itnet.model.evaluate import AnytimeReport, StepFn, anytime_poses, report, torch_step
from itnet.model.input_error import InputError
from itnet.model.plots import plot_anytime
from itnet.model.scanner import named_views
from itnet.upright import UPRIGHT_EVAL_DEG, sensed_ups

BATCH = 50
"""Clouds per network call."""


@dataclass(frozen=True)
class EvalReport:
    """What a measurement found and wrote: the accuracy curve, report.json's contents, the
    number of test objects and their orientation check, and the files."""

    anytime: AnytimeReport
    summary: dict[str, Any]
    objects: int
    orientation: dict[str, Any]
    report: Path
    plot: Path
    poses: Path
    scans: Path | None


@dataclass(frozen=True)
class Measured:
    """The model under measurement as ``anytime_poses`` runs it: its step, the iterations it was
    trained to, clouds per call, points per cloud, the category it knows, and the up direction's
    error (degrees; None: no up) with the steps its runs take free before being held upright."""

    step: StepFn
    trained_iterations: int
    batch: int
    points: int
    trained_on: str
    symmetry: str | None
    up: float | None
    up_free_steps: int


def evaluate_model(options: EvalOptions) -> EvalReport:
    """Measure ``options``' model on its category's test views; write the report, the poses
    and the plot into ``options.out``. Raises InputError for a bad choice of model, category
    or view rule."""
    measured = measured_model(options)
    try:
        cat = model_category(options.category, measured.trained_on, measured.symmetry)
    except ValueError as err:
        raise InputError(str(err)) from None
    try:
        views = named_views(options.scanner, cat.name)
    except ValueError as err:
        raise InputError(f"--scanner: {err}") from None
    scans, orientation = test_scans(options.data, cat, options.views, options.seed, views,
                                    options.cache, options.frame, options.check_orientation)  # fmt: skip
    ups = None
    if measured.up is not None:  # each scan's true up, tilted as a gravity sensor's would be
        ups = sensed_ups(scans.poses, measured.up, np.random.default_rng(options.seed + 1))
    poses = anytime_poses(measured.step, scans, options.iterations, measured.points,
                          batch=measured.batch, ups=ups, free_steps=measured.up_free_steps)  # fmt: skip
    anytime, rot, trans = report(poses, scans, cat.symmetry)
    up = {"up_error_deg": measured.up, "up_free_steps": measured.up_free_steps}
    summary = {
        "source": str(options.checkpoint or options.onnx),
        "category": cat.name,
        "symmetry": cat.symmetry,
        "orientation": orientation,
        "views": options.views,
        "scanner": options.scanner,
        "seed": options.seed,
        "points": measured.points,
        **({} if measured.up is None else up),
        **anytime.model_dump(),
    }
    out = options.out
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(summary, indent=1))
    np.savez_compressed(out / "poses.npz", poses=poses, truth=scans.poses, radii=scans.radii)
    title = (f"{cat.name} ({cat.symmetry}): {anytime.scans} partial scans ({options.scanner} "
             "views) of held-out objects")  # fmt: skip
    plot_anytime(anytime, rot, trans, measured.trained_iterations, out / "anytime.png", title)
    if options.dump_scans is not None:
        dump_scans(scans, options.dump_scans)
    return EvalReport(anytime, summary, len(set(scans.names)), orientation, out / "report.json",
                      out / "anytime.png", out / "poses.npz", options.dump_scans)  # fmt: skip


def measured_model(options: EvalOptions) -> Measured:
    """The checkpoint (run by torch) or the exported model (by onnxruntime) ``options`` name,
    with the points and the up direction ``options`` give or, where they do not, the model's
    own. Raises InputError unless exactly one is named."""
    if (options.checkpoint is None) == (options.onnx is None):
        raise InputError("give exactly one of --checkpoint or --onnx")
    if options.checkpoint is not None:
        from itnet.model.train import load_checkpoint

        net, state = load_checkpoint(options.checkpoint)
        config = state["config"]
        return Measured(
            step=torch_step(net),
            trained_iterations=config["iterations"],
            batch=BATCH,
            points=int(config["points"]) if options.points is None else options.points,
            trained_on=config["category"],
            symmetry=config.get("symmetry"),
            up=options.up,
            up_free_steps=0,
        )
    from itnet.pose.runtime import load_model

    model = load_model(options.onnx, warm_up=False)
    card = model.card
    up = options.up
    if up is None and card.requires_up:  # served only with up: measured only so
        up = UPRIGHT_EVAL_DEG
    return Measured(
        step=lambda x, p: model.step(x, p)[0],
        trained_iterations=card.trained_iterations,
        # int8 graphs quantise activations with one scale per call: batched clouds would
        # influence each other. The runtime steps one cloud at a time, and so does this.
        batch=1 if card.precision == "int8" else BATCH,
        points=card.points if options.points is None else options.points,
        trained_on=card.category,
        symmetry=card.symmetry,
        up=up,
        up_free_steps=0 if up is None else card.up_free_steps,
    )


def dump_scans(scans: ScanSet, folder: Path) -> Path:
    """Write each scan as scan_NNNN.npy (float32) into ``folder``, with labels.json: each
    file's true pose, radius and object. Returns the folder."""
    folder.mkdir(parents=True, exist_ok=True)
    labels = {}
    for i, cloud in enumerate(scans.clouds):
        name = f"scan_{i:04d}.npy"
        np.save(folder / name, cloud.astype(np.float32))
        labels[name] = {
            "T_canonical_from_input": scans.poses[i].tolist(),
            "radius": float(scans.radii[i]),
            "object": scans.names[i],
        }
    (folder / "labels.json").write_text(json.dumps(labels))
    return folder
