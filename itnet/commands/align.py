"""``itnet align A B`` (also ``itnet-align``): T_b_from_a, the transform that moves cloud A onto B.

Both canonical poses are the ones ``itnet pose`` serves (the same request, planned the same way;
in-process, or a running service with ``--server``): ``T_b_from_a = inv(T_canonical_from_b) ·
T_canonical_from_a``. The symmetric hypotheses, optional ICP and the choice between them are in
``itnet.alignment.pipeline`` and ``itnet.alignment.hypotheses``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import typer

from itnet.commands import UNITS_HELP, check_units, check_xyz
from itnet.commands.pose import request_from_options
from itnet.pose.request import field_help

if TYPE_CHECKING:
    from itnet.pose.request import PoseRequest

SYMMETRY_CHOICES = ("auto", "none", "yaw180", "yaw90", "yaw")
LOW_CONFIDENCE = 0.3


def align(
    cloud_a: Path = typer.Argument(
        ..., help="Cloud A, the one to move (.ply .pcd .xyz .pts .npy)."
    ),
    cloud_b: Path = typer.Argument(..., help="Cloud B, the reference (same object, same unit)."),
    model: str = typer.Option(
        "chair",
        help="Model name (a shipped one, or one in --model-dir); 'auto': classify the clouds "
        "and use their category's model.",
    ),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    budget_ms: float = typer.Option(1000.0, help="Time budget of each cloud's pose, in ms."),
    max_iterations: int | None = typer.Option(None, help=field_help("max_iterations")),
    server: str | None = typer.Option(
        None, "--server", help="URL of a running itnet service (default: run the model here)."
    ),
    refine: bool | None = typer.Option(
        None,
        "--refine/--no-refine",
        help="Refine the candidates with point-to-plane ICP (open3d). Default: on when open3d "
        "is installed (the 'refine' extra), off otherwise; --no-refine skips it (faster, "
        "fewer pairs aligned).",
        show_default=False,
    ),
    starts: int | None = typer.Option(
        None,
        "--starts",
        "--ensemble",
        min=1,
        max=16,
        help="Runs fused into each cloud's pose, each from another turn about z (the pose "
        "request's ensemble; default: the model's).",
    ),
    candidates: int = typer.Option(
        12, min=1, max=64, help="Distinct hypotheses kept after ranking (refined with --refine)."
    ),
    symmetry: str = typer.Option(
        "auto",
        help="Symmetry hypotheses: auto (from the model's category and card), none, yaw180, yaw90, yaw.",
    ),
    finalists: int = typer.Option(
        4, min=1, max=64, help="With --refine: candidates that get ICP's fine stage."
    ),
    up: str | None = typer.Option(
        None,
        help="Which way is up in both clouds, 'x,y,z' (scans from a sensor held level, e.g. "
        "'0,-1,0' for a camera whose image y points down): each pose is held upright, only its "
        "turn about up and its position are estimated. Needed by models that require up "
        "(`itnet models`).",
        callback=check_xyz,
    ),
    up_a: str | None = typer.Option(
        None, help="Which way is up in cloud A, 'x,y,z' (overrides --up for A).", callback=check_xyz
    ),
    up_b: str | None = typer.Option(
        None, help="Which way is up in cloud B, 'x,y,z' (overrides --up for B).", callback=check_xyz
    ),
    viewpoint: str | None = typer.Option(
        None,
        help="Where the sensor was in both clouds' frames, 'x,y,z' ('0,0,0' for depth-camera "
        "clouds in their own frames): each pose's centre is finished by it.",
        callback=check_xyz,
    ),
    output: Path | None = typer.Option(None, "--output", "-o", help="Write A moved onto B (.ply)."),
    units: str | None = typer.Option(None, help=UNITS_HELP, callback=check_units),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Estimate T_b_from_a (moves A onto B) from the two clouds' canonical poses and print it."""
    from itnet.alignment.hypotheses import category_symmetry
    from itnet.alignment.pipeline import AlignOptions, CloudEstimateError, align_clouds
    from itnet.alignment.refine import RefineUnavailable, require_open3d
    from itnet.cloud_io import CloudReadError, read_cloud, write_ply
    from itnet.geometry import apply_rigid

    if symmetry not in SYMMETRY_CHOICES:
        _fail(f"--symmetry must be one of {', '.join(SYMMETRY_CHOICES)}, got {symmetry!r}")
    if output is not None and output.suffix.lower() != ".ply":
        _fail(f"--output must be a .ply file, got {output}")
    try:
        points_a, points_b = read_cloud(cloud_a), read_cloud(cloud_b)
    except CloudReadError as err:
        _fail(str(err))

    try:
        if refine is not False:
            require_open3d()  # imported up front, so the reported time is the work's
            refine = True
    except RefineUnavailable as err:
        if refine:  # asked for by name
            _fail(str(err), code=1)
        typer.echo(f"note: no ICP refinement: {err}", err=True)
        refine = False
    ups = {"up_a": up if up_a is None else up_a, "up_b": up if up_b is None else up_b}
    if model == "auto":
        model = _auto_model(server, model_dir, points_a, points_b, budget_ms, units, ups)
    request = request_from_options(
        budget_ms=budget_ms, max_iterations=max_iterations, model=model, ensemble=starts,
        viewpoint=viewpoint, units=units,
    )  # fmt: skip
    estimate, (category, declared, requires_up), close = _estimator(server, request, model_dir)
    if requires_up and None in ups.values():
        close()
        _fail(
            f"model {model!r} needs which way is up in both clouds: give --up x,y,z (both), or "
            "--up-a and --up-b (its poses are measured, and served, only with it)"
        )
    options = AlignOptions(
        symmetry=category_symmetry(category, declared) if symmetry == "auto" else symmetry,
        refine=refine,
        candidates=candidates,
        finalists=finalists,
    )
    try:
        result = align_clouds(points_a, points_b, estimate, options, **ups)
    except ValueError as err:  # an up that is not a direction (the zero vector)
        _fail(str(err))
    except CloudEstimateError as err:
        path = cloud_a if err.cloud == "A" else cloud_b
        _fail(f"{path}: {err.__cause__}", code=_exit_code(err.__cause__))
    finally:
        close()

    if output is not None:
        write_ply(output, apply_rigid(result.T_b_from_a, points_a))
    if as_json:
        reply = {"cloud_a": str(cloud_a), "cloud_b": str(cloud_b), "model": model,
                 "symmetry": options.symmetry, **result.to_dict(),
                 **{k: v for k, v in ups.items() if v is not None},
                 "output": None if output is None else str(output)}  # fmt: skip
        typer.echo(json.dumps(reply))
    else:
        _print_summary(result)
    if result.confidence["confidence"] < LOW_CONFIDENCE:
        typer.echo(
            f"warning: low confidence {result.confidence['confidence']:.2f}: the clouds overlap "
            "little or the object looks alike in several poses; check the result (--output)",
            err=True,
        )


def _fail(message: str, code: int = 2) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def _exit_code(cause: BaseException | None) -> int:
    """2 for a cloud the estimator refused (bad input), 1 for anything else (service down)."""
    from itnet.clients import ItnetRequestError
    from itnet.pose.errors import PoseError

    if isinstance(cause, PoseError):
        return 2 if cause.status < 500 else 1
    if isinstance(cause, ItnetRequestError) and cause.status is not None and cause.status < 500:
        return 2
    return 1


def _auto_model(server, model_dir, points_a, points_b, budget_ms, units, ups) -> str:  # type: ignore[no-untyped-def]
    """The pose model for ``--model auto``: in-process, both clouds classified together (one
    object; levelled by their ups where both are given); with ``--server``, the service's
    ``model: "auto"`` on cloud A (with A's up). Says which on stderr; fails (exit 2) when the
    category has no model."""
    if server is not None:
        from itnet.clients import ItnetClient, ItnetClientError

        with ItnetClient(server) as client:
            try:
                reply = client.estimate(
                    points_a, budget_ms=budget_ms, max_iterations=1, model="auto", units=units,
                    up=ups["up_a"],
                ).raw  # fmt: skip
            except ItnetClientError as err:
                _fail(f"model auto at {server}: {err}", code=_exit_code(err))
        chosen = str(reply["model"])
        seen = f"{reply.get('category')} ({reply.get('category_probability', 0):.2f})"
        unsure = bool(reply.get("unsure"))
    else:
        from itnet.commands.in_process import all_models, get_classifier
        from itnet.pose.errors import BadCloudError
        from itnet.pose.recognition import classify_together, pose_model_for

        try:
            recognition = classify_together(
                get_classifier(model_dir), [points_a, points_b], units=units,
                ups=[ups["up_a"], ups["up_b"]],
            )  # fmt: skip
        except BadCloudError as err:
            _fail(str(err))
        loaded = pose_model_for(recognition.category, all_models(model_dir))
        if loaded is None:
            _fail(
                f"the clouds look like a {recognition.category} "
                f"({recognition.probability:.2f}) and no {recognition.category} model is loaded"
            )
        chosen, unsure = loaded.card.name, recognition.unsure
        seen = f"{recognition.category} ({recognition.probability:.2f})"
    typer.echo(f"auto: {seen}{', unsure' if unsure else ''}: model {chosen}", err=True)
    return chosen


def _estimator(server: str | None, request: PoseRequest, model_dir: Path | None):  # type: ignore[no-untyped-def]
    """(pose estimator, (the model's category, its declared symmetry, whether it requires up), a
    close function) for in-process or --server."""
    from itnet.alignment.estimators import client_estimator, in_process_estimator

    if server is None:
        from itnet.commands.in_process import get_catalog, get_model

        card = get_model(str(request.model), model_dir).card
        estimate = in_process_estimator(get_catalog(model_dir), request)
        return estimate, (card.category, card.symmetry, card.requires_up), lambda: None

    from itnet.clients import ItnetClient, ItnetClientError

    client = ItnetClient(server)
    try:
        listed = client.models()
    except ItnetClientError as err:
        client.close()
        _fail(f"cannot use the service at {server}: {err}", code=1)
    return (
        client_estimator(client, request),
        _category(listed, str(request.model)),
        (client.close),
    )


def _category(listed: object, model: str) -> tuple[str, str, bool]:
    """The category, symmetry and ``requires_up`` of ``model`` in a ``GET /v1/models`` reply
    ('', 'none' and False when it does not say)."""
    entries = listed.get("models", listed) if isinstance(listed, dict) else listed
    if isinstance(entries, dict):
        entries = [
            {"name": k, **v} if isinstance(v, dict) else {"name": k} for k, v in entries.items()
        ]
    for entry in entries if isinstance(entries, list) else []:
        if isinstance(entry, dict) and entry.get("name") == model:
            category, symmetry = str(entry.get("category", "")), str(entry.get("symmetry", "none"))
            return category, symmetry, bool(entry.get("requires_up", False))
    return "", "none", False


def _print_summary(result) -> None:  # type: ignore[no-untyped-def]
    """The matrix, then one line: rotation, translation, iterations, time, hypothesis, fit."""
    import numpy as np

    from itnet.alignment.hypotheses import same_alignment
    from itnet.geometry import rotation_angle_deg

    t = result.T_b_from_a
    shift = float(np.linalg.norm(t[:3, 3]))
    typer.echo("T_b_from_a (moves A onto B):")
    for row in t:
        typer.echo("  " + " ".join(f"{v:11.6f}" for v in row))
    chosen = result.hypotheses[result.chosen]
    times = result.timings_ms
    refine = f", icp {times['refine']:.1f} ms" if chosen.initial is not None else ""
    typer.echo(
        f"rotation {float(rotation_angle_deg(t[:3, :3])):.2f} deg, translation "
        f"[{t[0, 3]:.4g}, {t[1, 3]:.4g}, {t[2, 3]:.4g}] (|t| {shift:.4g}), "
        f"{result.iterations} iterations, {times['total']:.1f} ms (itnet {times['itnet']:.1f} ms"
        f"{refine}); hypothesis {chosen.source}, fitness {chosen.fitness:.3f}, "
        f"rmse {chosen.rmse:.4g}, confidence {result.confidence['confidence']:.2f}"
    )
    if chosen.icp is not None:
        typer.echo(
            f"icp (point-to-plane, open3d): fitness {chosen.icp['fitness']:.3f}, "
            f"inlier rmse {chosen.icp['rmse']:.4g} (correspondences within "
            f"{result.icp_distance:.4g})"
        )
    first = result.hypotheses[0]
    if result.chosen != 0 and not same_alignment(
        first.T_b_from_a, chosen.T_b_from_a, result.scale, 10.0, 0.1
    ):
        typer.echo(
            f"note: of {result.considered} hypotheses, {len(result.hypotheses)} distinct ones were "
            f"kept; the composed poses ({first.source}, fitness {first.fitness:.3f}) lost to "
            f"{chosen.source}, which fits the geometry clearly better after ICP"
        )
