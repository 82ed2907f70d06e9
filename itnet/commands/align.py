"""``itnet align A B`` (also ``itnet-align``): T_b_from_a, the transform that moves cloud A onto B.

The options are ``AlignRequest``'s fields; in-process, or ``POST /v1/align`` at a running service
with ``--server`` (the same request, the same code). Both canonical poses are the ones
``itnet pose`` serves; ``T_b_from_a = inv(T_canonical_from_b) · T_canonical_from_a`` is the prior,
and a rival replaces it only where it is more likely right (``itnet.alignment.pipeline``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import typer

from itnet.alignment.request import AlignRequest
from itnet.commands.request_options import REQUEST, request_options, xyz_option

LOW_PROBABILITY = 0.5


@request_options(AlignRequest)
def align(
    cloud_a: Path = typer.Argument(
        ..., help="Cloud A, the one to move (.ply .pcd .xyz .pts .npy)."
    ),
    cloud_b: Path = typer.Argument(..., help="Cloud B, the reference (same object, same unit)."),
    model_dir: Path | None = typer.Option(None, help="Folder of .onnx models (default: shipped)."),
    server: str | None = typer.Option(
        None,
        "--server",
        help="URL of a running itnet service: POST /v1/align there (default: run the models here).",
    ),
    up: str | None = typer.Option(
        None,
        help="Which way is up in both clouds, 'x,y,z' (scans from a sensor held level, e.g. "
        "'0,-1,0' for a camera whose image y points down): each pose is held upright, only its "
        "turn about up and its position are estimated. Needed by models that require up "
        "(`itnet models`). --up-a and --up-b override it for one cloud.",
        callback=xyz_option,
    ),
    output: Path | None = typer.Option(None, "--output", "-o", help="Write A moved onto B (.ply)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
    request: AlignRequest = REQUEST,
) -> None:
    """Estimate T_b_from_a (moves A onto B) from the two clouds' canonical poses and print it."""
    from itnet.cloud_io import CloudReadError, read_cloud, write_ply
    from itnet.geometry import apply_rigid

    if output is not None and output.suffix.lower() != ".ply":
        _fail(f"--output must be a .ply file, got {output}")
    try:
        points_a, points_b = read_cloud(cloud_a), read_cloud(cloud_b)
    except CloudReadError as err:
        _fail(str(err))
    request = request.model_copy(update={"up_a": request.up_a or up, "up_b": request.up_b or up})
    if request.model == "auto":
        chosen = _auto_model(server, model_dir, points_a, points_b, request)
        request = request.model_copy(update={"model": chosen})
    if server is None:
        result = _align_here(request, model_dir, points_a, points_b, (cloud_a, cloud_b))
        reply = {"model": request.model, "symmetry": result[1], **result[0].to_dict()}
    else:
        reply = _align_there(server, request, points_a, points_b, (cloud_a, cloud_b))
    if output is not None:
        write_ply(output, apply_rigid(np.asarray(reply["T_b_from_a"], np.float64), points_a))
    if as_json:
        ups = {k: v for k, v in (("up_a", request.up_a), ("up_b", request.up_b)) if v is not None}
        typer.echo(json.dumps({"cloud_a": str(cloud_a), "cloud_b": str(cloud_b), **reply, **ups,
                               "output": None if output is None else str(output)}))  # fmt: skip
    else:
        _print_summary(reply)
    if reply["probability"] < LOW_PROBABILITY:
        typer.echo(
            f"warning: the alignment is {reply['probability']:.0%} likely right: the clouds "
            "overlap little, the poses disagree, or the object looks alike in several poses; "
            "check the result (--output)",
            err=True,
        )


def _refine(asked: bool | None) -> bool:
    """Whether ICP runs (``itnet.alignment.refine.refine_wanted``): exit 1 where it was asked for
    by name and open3d is absent; a note on stderr where the default finds it absent."""
    from itnet.alignment.refine import RefineUnavailable, refine_wanted

    try:
        return refine_wanted(asked, lambda why: typer.echo(f"note: no ICP refinement: {why}",
                                                           err=True))  # fmt: skip
    except RefineUnavailable as err:
        _fail(str(err), code=1)


def _align_here(request: AlignRequest, model_dir: Path | None, points_a: Any, points_b: Any,
                paths: tuple[Path, Path]) -> tuple[Any, str]:  # fmt: skip
    """The alignment in this process -> (Alignment, the symmetry of its rivals)."""
    from itnet.alignment.estimators import in_process_estimator
    from itnet.alignment.pipeline import CloudEstimateError, align_clouds
    from itnet.commands.in_process import get_catalog, get_model

    card = get_model(str(request.model), model_dir).card
    if card.requires_up and (request.up_a is None or request.up_b is None):
        _fail(
            f"model {card.name!r} needs which way is up in both clouds: give --up x,y,z (both), "
            "or --up-a and --up-b (its poses are measured, and served, only with it)"
        )
    options = request.options(card, _refine(request.refine))
    estimate = in_process_estimator(get_catalog(model_dir), request.pose_request())
    try:
        result = align_clouds(points_a, points_b, estimate, options, request.up_a, request.up_b,
                              started=time.perf_counter())  # fmt: skip
    except ValueError as err:  # an up that is not a direction (the zero vector)
        _fail(str(err))
    except CloudEstimateError as err:
        path = paths[0] if err.cloud == "A" else paths[1]
        _fail(f"{path}: {err.__cause__}", code=_exit_code(err.__cause__))
    return result, options.symmetry


def _align_there(server: str, request: AlignRequest, points_a: Any, points_b: Any,
                 paths: tuple[Path, Path]) -> dict:  # fmt: skip
    """``POST /v1/align`` at ``server`` -> its reply; a refusal naming a cloud names its file."""
    from itnet.clients import ItnetClient, ItnetClientError

    with ItnetClient(server) as client:
        try:
            return dict(client.align(points_a, points_b, request))
        except ItnetClientError as err:
            text = str(err)
            for name, path in zip(("A", "B"), paths):
                text = text.replace(f"cloud {name}: ", f"{path}: ")
            _fail(f"{text}", code=_exit_code(err))


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


def _auto_model(server: str | None, model_dir: Path | None, points_a: Any, points_b: Any,
                request: AlignRequest) -> str:  # fmt: skip
    """The pose model for ``--model auto``: in-process, both clouds classified together (one
    object; levelled by their ups where both are given); with ``--server``, the service's
    ``model: "auto"`` on cloud A (with A's up). Says which on stderr; fails (exit 2) when the
    category has no model."""
    if server is not None:
        from itnet.clients import ItnetClient, ItnetClientError

        with ItnetClient(server) as client:
            try:
                reply = client.estimate(
                    points_a, budget_ms=request.budget_ms, max_iterations=1, model="auto",
                    units=request.units, up=request.up_a,
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
                get_classifier(model_dir), [points_a, points_b], units=request.units,
                ups=[request.up_a, request.up_b],
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


def _print_summary(reply: dict) -> None:
    """The matrix, then one line: rotation, translation, iterations, time, hypothesis, how likely
    right, and the runner-up."""
    t = np.asarray(reply["T_b_from_a"], dtype=np.float64)
    times = reply["timings_ms"]
    typer.echo("T_b_from_a (moves A onto B):")
    for row in t:
        typer.echo("  " + " ".join(f"{v:11.6f}" for v in row))
    second = reply.get("runner_up")
    runner_up = "" if second is None else (
        f"; runner-up {second['hypothesis']} {second['probability']:.0%}")  # fmt: skip
    typer.echo(
        f"rotation {reply['rotation_deg']:.2f} deg, translation "
        f"[{t[0, 3]:.4g}, {t[1, 3]:.4g}, {t[2, 3]:.4g}] (|t| {np.linalg.norm(t[:3, 3]):.4g}), "
        f"{reply['iterations']} iterations, {times['total']:.1f} ms (itnet {times['itnet']:.1f} "
        f"ms); hypothesis {reply['hypothesis']}, {reply['probability']:.0%} likely right, "
        f"fitness {reply['fitness']:.3f}{runner_up}"
    )
    if reply["considered"]:
        typer.echo(
            f"the composed pose was in doubt: {len(reply['hypotheses']) - 1} distinct rivals of "
            f"{reply['considered']} hypotheses judged"
        )
