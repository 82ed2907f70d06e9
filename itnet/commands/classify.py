"""``itnet classify FILE...`` (which category is each cloud) and ``itnet classify-experiment``
(the paper's classification table on partial ModelNet10)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer

from itnet.commands import check_units
from itnet.commands.request_options import xyz_option
from itnet.pose.request import PoseRequest


def classify(
    files: list[Path] = typer.Argument(..., help="Cloud files: .ply .pcd .xyz .pts .txt .npy"),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    top: int = typer.Option(3, help="Candidates to print (most probable first)."),
    units: str | None = typer.Option(
        None, help=PoseRequest.field_help("units"), callback=check_units
    ),
    looks: int = typer.Option(
        1,
        min=1,
        max=16,
        help="Classify K turned random subsets of each cloud and average them "
        "(more accurate, about K times the time).",
    ),
    up: str | None = typer.Option(
        None,
        help="Which way is up in the clouds, 'x,y,z' (gravity): each is classified levelled, by "
        "the upright classifier where one is installed.",
        callback=xyz_option,
    ),
    second_looks: int | None = typer.Option(
        None,
        min=1,
        max=16,
        help="A single look whose answer is unsure is followed by more, this many looks in all "
        "(1: never; default: the service's, 4): more accurate, that many times the time for "
        "those clouds.",
    ),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line."),
) -> None:
    """Print each cloud's category and probabilities. Bad files are reported and skipped (exit 2)."""
    from itnet.cloud_io import CloudReadError, read_cloud
    from itnet.commands.in_process import get_classifier
    from itnet.pose.errors import BadCloudError
    from itnet.pose.recognition import classify as recognise

    classifier = get_classifier(model_dir)
    failed = False
    for path in files:
        try:
            result = recognise(
                classifier, read_cloud(path), top=top, units=units, looks=looks, up=up,
                **({} if second_looks is None else {"second_looks": second_looks}),
            )  # fmt: skip
        except (CloudReadError, BadCloudError) as err:
            message = str(err) if str(err).startswith(str(path)) else f"{path}: {err}"
            typer.echo(f"error: {message}", err=True)
            failed = True
            continue
        if as_json:
            typer.echo(json.dumps({"file": str(path), **result.as_dict()}))
        else:
            others = ", ".join(f"{c.category} {c.probability:.3f}" for c in result.candidates[1:])
            unsure = " (unsure)" if result.unsure else ""
            unsure += " (upright)" if result.upright else ""
            unsure += f" ({result.looks} looks)" if result.second_opinion else ""
            typer.echo(
                f"{path}: {result.category} {result.probability:.3f}{unsure}"
                + (f"; then {others}" if others else "")
                + f" ({result.elapsed_ms:.1f} ms)"
            )
    if failed:
        raise typer.Exit(2)


def classify_experiment(
    data: Path = typer.Option(
        Path("../shared/data/modelnet10"), help="ModelNet-style root (DATA/CLASS/{train,test})."
    ),
    out: Path = typer.Option(Path("runs/cls"), help="Folder of the rows' runs."),
    steps: int = typer.Option(1200, help="Optimiser steps of every row (the same budget each)."),
    batch: int = typer.Option(32, help="Views per step."),
    points: int = typer.Option(256, help="Points per view."),
    decay_every: int = typer.Option(240, help="Multiply the learning rate by 0.7 every N steps."),
    eval_every: int = typer.Option(200, help="Validate and checkpoint every N steps."),
    test_views: int = typer.Option(4, help="Fixed views per test shape (half occluded)."),
    threads: int = typer.Option(1, help="torch threads."),
    compile: bool = typer.Option(
        True, help="torch.compile the training step (~1.7x on a CPU; eager if it cannot compile)."
    ),
    seed: int = typer.Option(0),
    cache: Path = typer.Option(Path("cache"), help="Cache of shapes and fixed views."),
    docs: Path | None = typer.Option(
        Path("docs"),
        help="Write classification.md/.json and confusion_table.png here (none: skip).",
    ),
    report_only: bool = typer.Option(False, help="Only rewrite the report from finished rows."),
) -> None:
    """Train every row of the table (resumable: finished rows are skipped), then write the
    report. Rows: none, T-Net (1, 2 iterations), T-Net + regulariser (1, 2), IT-Net (1, 2)."""
    from itnet.model.classify.experiment import ORDER, run_table
    from itnet.model.classify.train import ClassifyConfig

    base = ClassifyConfig(
        data=data,
        cache=cache,
        steps=steps,
        batch=batch,
        points=points,
        decay_every=decay_every,
        eval_every=eval_every,
        test_views=test_views,
        threads=threads,
        seed=seed,
        compile=compile,
    )
    if not report_only:
        run_table(base, out, ORDER)
    if docs is not None:
        from itnet.model.classify.report import write_report

        for path in write_report(out, docs):
            typer.echo(f"wrote {path}")


def classify_export(
    run: Path = typer.Argument(
        ...,
        help="A finished run folder (best.pt, result.json), or a shipped checkpoint "
        "(lab/weights/classifier.pt): its run is remade from the config it keeps.",
    ),
    out: Path = typer.Option(
        Path("itnet/models/classifier.onnx"),
        help="Output .onnx file (an upright run's: itnet/models/classifier_upright.onnx).",
    ),
    points: int | None = typer.Option(None, help="Points per cloud at serving (default: trained)."),
    canonical_points: int | None = typer.Option(
        None,
        min=1,
        help="The canonicaliser finds the pose from this many of the points (random ones), the "
        "classifier sees them all: faster (docs/classification.md). Default: as trained (all).",
    ),
    int8: bool = typer.Option(
        False, "--int8", help="Quantise the per-point layers to int8 (faster on 2 cores)."
    ),
    target: float = typer.Option(
        0.95, help="Unsure threshold: the lowest at which this share of validation views is right."
    ),
    report: Path | None = typer.Option(
        None,
        help="Also write the card, the graph's test metrics (per class, confusion matrix) and "
        "the threshold's effect on the test views (JSON).",
    ),
    confusion: Path | None = typer.Option(
        None, help="Also plot the graph's test confusion matrix here (PNG; docs/confusion.png)."
    ),
    weights_out: Path | None = typer.Option(
        None,
        help="Also copy the run's best torch weights here, without optimiser state "
        "(what a later fine-tune starts from: classify-train --init-from).",
    ),
    fuse_with: list[Path] = typer.Option(
        [],
        help="Also these classifier checkpoints' heads, behind the same canonicaliser (they must "
        "hold the run's transformer weights: heads trained with --freeze-transformer); the graph "
        "answers with their mean log-probability (docs/classification.md).",
    ),
    cascade: float | None = typer.Option(
        None,
        min=0.0,
        max=1.0,
        help="With --fuse-with: the other heads run only for looks whose first head (the run's; "
        "give the cheaper one first) has a top probability below this, the rest get the first "
        "head's answer: about the fused accuracy at a fraction of its time "
        "(docs/classification.md). Default: every head always.",
    ),
    beside: Path = typer.Option(
        Path("itnet/models/classifier.onnx"),
        help="An upright run's graph is served fused with this classifier for any orientation: "
        "its card's accuracy and threshold are measured so.",
    ),
) -> None:
    """Export a run's best classifier (canonicaliser included) to one ONNX graph, check it
    against torch on random clouds, then measure the graph itself on the run's validation and
    test views: its card carries that accuracy and the unsure threshold chosen on validation."""
    import tempfile

    import numpy as np
    import onnx
    import torch

    from itnet.export.classifier_export import (
        card_from_run,
        export_classifier,
        fused_probabilities,
        heads_name,
        score_graph,
        trained_points,
        unsure_split,
    )
    from itnet.export.onnx_export import save_with_card
    from itnet.export.quantize import quantize_point_layers
    from itnet.model.classify.train import load_classifier, metrics
    from itnet.model_card import ClassifierCard
    from itnet.pose.runtime import LoadedClassifier, load_any

    if cascade is not None and not fuse_with:
        raise typer.BadParameter("--cascade needs heads to cascade to (--fuse-with)")
    if cascade is not None and int8:
        raise typer.BadParameter("--cascade is for float32 graphs (not with --int8)")
    with tempfile.TemporaryDirectory() as made:  # a run remade from a checkpoint
        if run.is_file():
            from itnet.model.classify.train import run_of_checkpoint

            try:
                run = run_of_checkpoint(run, Path(made) / "run")
            except ValueError as err:
                typer.echo(f"error: {err}", err=True)
                raise typer.Exit(2) from None
        net, _ = load_classifier(run / "best.pt")
        fused = [load_classifier(path)[0] for path in fuse_with]
        if canonical_points is None:  # as trained
            canonical_points = net.config.canonical_points
        result = json.loads((run / "result.json").read_text())
        provisional = ClassifierCard(
            classes=result["classes"],
            points=points or trained_points(run),
            transformer=result["variant"],
            upright=json.loads((run / "config.json").read_text()).get("upright") is not None,
            canonical_points=canonical_points,
            head=heads_name([net, *fused]),
            cascade=cascade,
        )
        with tempfile.TemporaryDirectory() as tmp:
            try:
                graph = export_classifier(net, provisional, Path(tmp) / "float32.onnx", fused=fused)
            except ValueError as err:
                typer.echo(f"error: {err}", err=True)
                raise typer.Exit(2) from None
            if cascade is not None:
                from itnet.export.cascade import cascade_graph

                onnx.save(cascade_graph(onnx.load(str(graph)), cascade), str(graph))
            if int8:
                quantize_point_layers(graph, out)
            else:
                out.parent.mkdir(parents=True, exist_ok=True)
                out.write_bytes(graph.read_bytes())
        loaded = load_any(out, warm_up=False)
        assert isinstance(loaded, LoadedClassifier)
        # as many points as the canonicaliser sees: then the torch net's pose is the graph's
        seen = min(provisional.points, canonical_points or provisional.points)
        x = np.random.default_rng(0).normal(size=(1, seen, 3)).astype(np.float32)
        with torch.no_grad():  # the cascade's answer is the fused one where the first is unsure
            from itnet.export.cascade import cascade_probabilities

            nets, cloud = [net, *fused], torch.from_numpy(x)
            expected = (
                fused_probabilities(nets, cloud)
                if cascade is None
                else cascade_probabilities(nets, cloud, cascade)
            ).numpy()
        diff = float(np.abs(loaded.probabilities(x) - expected).max())
        partner = None
        if loaded.card.upright:
            partner = load_any(beside, warm_up=False)
            if not isinstance(partner, LoadedClassifier) or partner.card.upright:
                typer.echo(
                    f"error: --beside {beside} is not a classifier for any orientation", err=True
                )
                raise typer.Exit(2)
        scores = score_graph(loaded, run, partner)
        measured = card_from_run(
            run, scores, points, target, None if partner is None else beside.name
        )
        card = measured.model_copy(
            update={
                "precision": loaded.card.precision,
                "canonical_points": canonical_points,
                "head": provisional.head,
                "cascade": cascade,
                "training": {
                    **measured.training,
                    **({"fused_with": [p.name for p in fuse_with]} if fuse_with else {}),
                },
            }
        )
        save_with_card(onnx.load(str(out)), card, out)
        test = result["test"]  # None: a run trained with --hold-test
        torch_test = "not measured" if test is None else f"{100 * test['accuracy']:.1f}%"
        typer.echo(
            f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, {card.precision}): "
            f"{card.transformer}, test accuracy {100 * card.accuracy:.1f}% on this graph "
            f"(torch: {torch_test}), validation "
            f"{100 * float(card.training['validation']):.1f}% "
            f"(torch: {100 * result['val']['accuracy']:.1f}%), threshold {card.threshold}; "
            f"max |onnx - torch| {diff:.2e} on a random cloud"
        )
        if weights_out is not None:
            from itnet.model.train import ship_checkpoint

            ship_checkpoint(run / "best.pt", weights_out)
            typer.echo(f"wrote {weights_out} ({weights_out.stat().st_size / 1e6:.1f} MB)")
        graph_test = {
            "classes": card.classes,
            "test": metrics(scores.test_probs, scores.test_labels, card.classes),
        }
        if report is not None:
            split = unsure_split(scores, card.threshold)
            report.write_text(
                json.dumps(
                    {"card": card.model_dump(), "unsure": split, "test": graph_test["test"]},
                    indent=1,
                )
            )
            typer.echo(f"test views at the threshold: {json.dumps(split)}; wrote {report}")
        if confusion is not None:
            from itnet.model.classify.report import plot_confusion

            name = f"{out.name} ({card.transformer}, {card.head})"
            typer.echo(f"wrote {plot_confusion(graph_test, confusion, name)}")


def classify_train(
    variant: str = typer.Option("itnet-2", help="Row of the table: none, tnet-1, ..., itnet-2."),
    data: Path = typer.Option(Path("../shared/data/modelnet10"), help="ModelNet-style root."),
    out: Path = typer.Option(Path("runs/cls-ship/itnet-2"), help="Run folder."),
    steps: int = typer.Option(3200, help="Optimiser steps."),
    lr: float = typer.Option(5e-4, help="Initial Adam learning rate."),
    decay_every: int = typer.Option(800, help="Multiply the learning rate by 0.7 every N steps."),
    bn_momentum: float = typer.Option(0.1, help="BatchNorm momentum at step 0 (floor 0.01)."),
    init_from: Path | None = typer.Option(None, help="Start from this checkpoint's weights."),
    balanced: bool = typer.Option(
        False,
        help="Classes weigh alike: drawn uniformly into batches, best.pt chosen on the "
        "validation's mean class accuracy.",
    ),
    up_weight: float = typer.Option(
        0.0,
        min=0.0,
        help="Also teach IT-Net to stand views up (weight of the up-axis term; 0: the paper's "
        "class loss alone).",
    ),
    stretch: float = typer.Option(
        1.0,
        min=1.0,
        help="Stretch each training shape along its axes by factors drawn log-uniformly in "
        "[1/S, S] before it is scanned (1: off): more shapes than the dataset has.",
    ),
    upright: float | None = typer.Option(
        None,
        min=0.0,
        help="Upright views: each levelled by its up direction with up to DEG degrees of error "
        "(validation and test: 2); the classifier for requests that give up. Default: full SO(3).",
    ),
    views: str = typer.Option(
        "occluded,paper",
        help="View rules of training, validation and test, comma-separated: occluded, paper, "
        "surface, base_hidden, each as rendered or by a depth camera (RULE+SENSOR, e.g. "
        "occluded+kinect_v2: at real sizes; docs/training.md).",
    ),
    elevation: str | None = typer.Option(
        None,
        help="MIN,MAX: cameras only this many degrees over the shape's horizon (e.g. -10,55: held "
        "above the floor, as scenes see furniture). Default: any direction.",
    ),
    canonical_points: int | None = typer.Option(
        None,
        min=1,
        help="The transformer finds its pose from this many of the points (random ones), as "
        "classify-export --canonical-points serves it. Default: all.",
    ),
    label_smoothing: float = typer.Option(
        0.0,
        min=0.0,
        max=0.5,
        help="Smooth the cross-entropy's targets by E (1 - E on the class; 0: off).",
    ),
    hold_test: bool = typer.Option(
        False,
        help="End without measuring the test split (an experiment whose choice is still open); "
        "classify-export measures the exported graph on it.",
    ),
    ema: float | None = typer.Option(
        None,
        min=0.0,
        max=1.0,
        help="Also keep an exponential moving average of the weights (decay per step, e.g. "
        "0.999), validated beside the raw weights; best.pt keeps whichever scores higher.",
    ),
    head: str = typer.Option(
        "pointnet",
        help="The classifier after the transformer: pointnet (the paper's) or local (each layer "
        "mixes in every point's nearest neighbours; docs/classification.md).",
    ),
    neighbours: int | None = typer.Option(
        None, min=1, help="Neighbours of each point (--head local; default 16)."
    ),
    transformer_from: Path | None = typer.Option(
        None,
        help="Start the transformer (only) from this classifier checkpoint's, e.g. a new head "
        "behind lab/weights/classifier.pt's canonicaliser.",
    ),
    freeze_transformer: bool = typer.Option(
        False, help="Do not train the transformer (its weights and BatchNorm statistics stay)."
    ),
    init_seed: int | None = typer.Option(
        None,
        help="Seed of the initialisation and the batches (default: the split's, 0): another "
        "network on the same training and validation split.",
    ),
    eval_every: int = typer.Option(200, help="Validate and checkpoint every N steps."),
    threads: int = typer.Option(1, help="torch threads."),
    compile: bool = typer.Option(
        True, help="torch.compile the training step (~1.7x on a CPU; eager if it cannot compile)."
    ),
    cache: Path = typer.Option(Path("cache"), help="Cache of shapes and fixed views."),
    batch: int = typer.Option(32, min=1, help="Views per step."),
    device: str = typer.Option("cpu", help="cpu | cuda"),
    data_workers: int = typer.Option(
        0, min=0, help="Processes making the views ahead of each step (for a GPU: ~2)."
    ),
) -> None:
    """Train one classifier (resumable), e.g. the shipped one: a table row trained longer."""
    from itnet.model.classify.train import ClassifyConfig, train

    rules = _view_rules(views, "--views")
    low_high = None if elevation is None else _degrees_range(elevation, "--elevation")
    config = ClassifyConfig(
        data=data,
        variant=variant,
        out=out,
        steps=steps,
        lr=lr,
        decay_every=decay_every,
        bn_momentum=(bn_momentum, 0.01),
        init_from=init_from,
        balanced=balanced,
        up_weight=up_weight,
        stretch=stretch,
        upright=upright,
        views=rules,
        elevation=low_high,
        canonical_points=canonical_points,
        label_smoothing=label_smoothing,
        ema=ema,
        hold_test=hold_test,
        head=head,
        neighbours=neighbours,
        transformer_from=transformer_from,
        freeze_transformer=freeze_transformer,
        init_seed=init_seed,
        eval_every=eval_every,
        threads=threads,
        cache=cache,
        compile=compile,
        batch=batch,
        device=device,
        data_workers=data_workers,
    )
    result = train(config, log_progress=True)
    test = result["test"]
    measured = (
        f"{100 * test['accuracy']:.1f}% ± {100 * test['standard_error']:.1f} ({test['scans']} views)"
        if test
        else "not measured (held back, or no test shapes)"
    )
    typer.echo(f"{variant}: validation {100 * result['val']['accuracy']:.1f}%, test {measured}")


def _view_rules(text: str, option: str) -> tuple[str, ...]:
    """'RULE,RULE+SENSOR,...' -> the view rule names, each known (``view_configs``), at least
    one; BadParameter otherwise."""
    from itnet.model.classify.data import view_configs

    rules = tuple(rule.strip() for rule in text.split(",") if rule.strip())
    try:
        view_configs(rules or ("",))
    except ValueError as error:
        raise typer.BadParameter(str(error), param_hint=option) from None
    return rules


def _degrees_range(text: str, option: str) -> tuple[float, float]:
    """'MIN,MAX' degrees, -90 < MIN <= MAX < 90 -> (MIN, MAX); BadParameter otherwise."""
    try:
        low, high = (float(part) for part in text.split(","))
    except ValueError:
        raise typer.BadParameter("two numbers, MIN,MAX", param_hint=option) from None
    if not -90 < low <= high < 90:
        raise typer.BadParameter("degrees with -90 < MIN <= MAX < 90", param_hint=option)
    return low, high


def classify_size_prior(
    classifier: Path = typer.Option(
        Path("itnet/models/classifier.onnx"), help="The exported classifier whose card to update."
    ),
    data: Path = typer.Option(Path("../shared/data/modelnet10"), help="ModelNet-style root."),
    views: int = typer.Option(2, help="Random views per training shape to fit the sizes on."),
    df: float = typer.Option(3.0, help="Student-t degrees of freedom of each class's log size."),
    weight: float = typer.Option(0.5, help="Weight of the size's log-likelihood."),
    split: str = typer.Option(
        "val", help="Where to measure it: 'val' (choose here) or 'test' (once, after choosing)."
    ),
    write: bool = typer.Option(False, help="Write the prior and its measurement into the card."),
    cache: Path = typer.Option(Path("cache"), help="Cache of shapes."),
    sizes: str = typer.Option(
        "inches",
        help="The shapes' sizes: 'inches' (ModelNet's units read as inches) or 'real' (each "
        "view at a real piece's size, drawn from the category's range: docs/training.md).",
    ),
    rules: str = typer.Option(
        "occluded,paper",
        help="View rules of the fitting and measuring views, in turn (RULE or RULE+SENSOR, "
        "as classify-train --views).",
    ),
) -> None:
    """Fit the classifier's size prior on views of the training shapes (ModelNet's units read
    as inches, or real sizes), measure top-1 with and without it on views of the validation or test shapes
    (4 a shape, seeded), and with --write store both in the classifier's card: then a request
    that gives its cloud's unit (``units``) lets the size count (``itnet.size_prior``)."""
    import onnx

    from itnet.export.onnx_export import save_with_card
    from itnet.model.classify.data import class_names, load_splits
    from itnet.model.classify.size_prior import accuracy_with_and_without, sized_views, source_radii
    from itnet.pose.runtime import LoadedClassifier, load_any
    from itnet.size_prior import fit_size_prior

    if split not in ("val", "test"):
        raise typer.BadParameter("--split must be val or test")
    if sizes not in ("inches", "real"):
        raise typer.BadParameter("--sizes must be inches or real")
    view_rules = _view_rules(rules, "--rules")
    real = sizes == "real"
    loaded = load_any(classifier, warm_up=False)
    if not isinstance(loaded, LoadedClassifier):
        raise typer.BadParameter(f"{classifier} is not a classifier")
    classes = class_names(data)
    if classes != list(loaded.card.classes):
        raise typer.BadParameter(f"{data}'s classes {classes} are not the card's")
    splits = load_splits(data, classes, 0.1, 0, cache)
    training = sized_views(
        splits["train"], source_radii(data, classes, "train"), views, seed=1, rules=view_rules,
        real=real,
    )  # fmt: skip
    kinds = ", ".join(view_rules)
    at = "at real sizes (docs/training.md#real-sizes)" if real else "its units read as inches"
    source = f"{data.name} training split, {views} views a shape ({kinds} views), {at}"
    prior = fit_size_prior(
        training.labels, training.radii_m, len(classes), df, weight, source=source
    )
    measured = sized_views(
        splits[split], source_radii(data, classes, split), 4, {"val": 2, "test": 3}[split],
        loaded.card.points, rules=view_rules, real=real,
    )  # fmt: skip
    scores = accuracy_with_and_without(loaded, measured, prior)
    for name, median, scale in zip(classes, prior.log_median, prior.log_scale):
        typer.echo(f"{name:12s} RMS radius of a view: median {math.exp(median):.3f} m, "
                   f"log spread {scale:.2f}")  # fmt: skip
    typer.echo(f"{split}: {json.dumps(scores)}")
    if loaded.card.size_prior is not None:  # what it would replace, on the same views
        current = accuracy_with_and_without(loaded, measured, loaded.card.size_prior)
        typer.echo(f"{split}, the card's prior now: {json.dumps(current)}")
    if write:
        evaluation = (
            f"{split} views ({scores['views']}, 4 a shape, {kinds} views in turn, "
            f"{'at real sizes' if real else 'in inches'}): top-1 {100 * scores['top1']:.1f}% alone, "
            f"{100 * scores['top1_with_size']:.1f}% with the size (paired gain "
            f"{100 * scores['gain']:+.1f} ± {100 * scores['gain_stderr']:.1f}); mean class "
            f"{100 * scores['mean_class']:.1f}% -> {100 * scores['mean_class_with_size']:.1f}%"
        )
        card = loaded.card.model_copy(
            update={"size_prior": prior.model_copy(update={"evaluation": evaluation})}
        )
        save_with_card(onnx.load(str(classifier)), card, classifier)
        typer.echo(f"wrote the size prior into {classifier}'s card")
