"""What ``itnet models`` lists: the models of a folder as the service lists them
(``GET /v1/models``: each card's category, symmetry, finishes, precision, points, runs and
accuracy, with this machine's step time), and that listing as a table of text.

    listing = list_models(Path("itnet/models"))
    print("\\n".join(listing_lines(listing)))

Torch-free: it loads the models with onnxruntime, as the service does.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from itnet.service.schemas import ModelInfo, ModelsResponse

HEADER = ("name", "category", "symmetry", "mirror", "centre", "up", "precision", "points", "runs",
          "verifier", "accuracy", "step", "")  # fmt: skip
"""The table's columns; the last marks the default model."""

LEGEND = (
    "runs: fused per estimate by default, as many as the budget holds, on the card's schedule "
    "('IxP pts', the first I steps on P points a run; 'K kept', then only the K runs the "
    "verifier finds likeliest); mirror: the planes (x: "
    "left-right, z: front-back) a single run's final pose is finished by, fused runs' too where "
    "--json says mirror_fused; centre: the final pose's object centre is finished by the card's "
    "correction (+vp: another for requests that give the sensor's position, +up for those that "
    "give up, +upvp for those that give both); up: 'needed' where a request must say which way "
    "is up in its cloud (--up); verifier: where the category has a learned verifier, what it "
    "does by default (verify: fused runs anchored on the likeliest, verify-if-fused where the "
    "default is one run; recheck:N, a doubted single run rechecked by N runs); accuracy: one "
    "run's, at (10 deg, 0.1 radius), before the mirror, see --json"
)
"""What the columns mean, printed under the table."""


@dataclass(frozen=True)
class ModelListing:
    """The folder listed and the service's reply for it."""

    folder: Path
    reply: ModelsResponse


def list_models(model_dir: Path | None = None) -> ModelListing:
    """The models in ``model_dir`` (default: the ones shipped in the package), loaded and warmed
    up by the service's own loader (so ``step_ms`` is this machine's), set up as at the
    service's start-up (the default model, the classifier if any), and listed by the route of
    ``GET /v1/models`` itself. Raises ModelLoadError for a folder without models."""
    import asyncio

    from itnet.pose.runtime import default_model_dir, load_models
    from itnet.service.api.routes.system import models as models_route
    from itnet.service.metrics import Metrics
    from itnet.service.settings import Settings
    from itnet.service.state import ServiceState

    folder = model_dir or default_model_dir()
    loaded = load_models(folder, threads=2, warm_up=True)
    state = ServiceState(Settings(model_dir=folder), Metrics(), models=loaded)
    state.load()
    return ModelListing(folder, asyncio.run(models_route(state)))


def listing_lines(listing: ModelListing) -> list[str]:
    """The table (one row per model, columns padded), the auto line where a classifier picks
    the model, and the legend."""
    reply = listing.reply
    rows = [HEADER, *(model_row(info) for info in reply.models)]
    widths = [max(len(row[i]) for row in rows) for i in range(len(HEADER))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]
    if reply.auto is not None:
        upright = ""
        if reply.auto.upright is not None:
            upright = "; an upright classifier joins it where the cloud's up is given (--up)"
        lines.append(
            f"auto: a classifier of {len(reply.auto.classes)} categories "
            f"({', '.join(reply.auto.classes)}) picks the pose model (--model auto){upright}"
        )
    lines.append(f"({len(reply.models)} model(s) in {listing.folder}; {LEGEND})")
    return lines


def model_row(info: ModelInfo) -> tuple[str, ...]:
    """One model's cells, in the order of ``HEADER``."""
    return (
        info.name,
        info.category,
        info.symmetry,
        ",".join(info.mirror_planes) or "-",
        centre_cell(info.centre, info.centre_viewpoint, info.centre_up, info.centre_up_viewpoint),
        "needed" if info.requires_up else "-",
        info.precision,
        str(info.points),
        runs_cell(info.recommended_ensemble, info.coarse_steps, info.halving),
        verifier_cell(
            info.verifier, info.verify_fused, info.recheck_runs, info.recommended_ensemble
        ),
        accuracy_cell(info.accuracy, info.recommended_iterations),
        f"{info.step_ms:.2f} ms",
        "default" if info.default else "",
    )


def runs_cell(runs: int, coarse: tuple[int, int] | None, halving: tuple[int, int] | None) -> str:
    """The runs column: the runs fused by default, and the card's plan where it has one: '8,
    4x64 pts, 3 kept' (the first 4 steps on 64 points a run, then the 3 likeliest runs)."""
    parts = [str(runs)]
    if coarse is not None:
        parts.append(f"{coarse[0]}x{coarse[1]} pts")
    if halving is not None and halving[1] < runs:
        parts.append(f"{halving[1]} kept")
    return ", ".join(parts)


def verifier_cell(name: str | None, verify: bool, recheck_runs: int, runs: int) -> str:
    """The verifier column: '-' without one, else what the card has it do by default: 'verify'
    where the default fuses runs, 'verify-if-fused' where it is one run (a request for several
    gets it), 'recheck:N' for a doubted single run."""
    if name is None:
        return "-"
    verifies = ["verify" if runs > 1 else "verify-if-fused"] if verify else []
    uses = verifies + ([f"recheck:{recheck_runs}"] if recheck_runs else [])
    return "+".join(uses) or "loaded"


def accuracy_cell(accuracy: dict[str, float], iterations: int) -> str:
    """'49.7% at 10 it.' (the card's figure at the recommended count), or '-' when unmeasured."""
    value = accuracy.get(str(iterations))
    return "-" if value is None else f"{100 * value:.1f}% at {iterations} it."


def centre_cell(plain: bool, viewpoint: bool, up: bool = False, up_viewpoint: bool = False) -> str:
    """'yes', 'yes+vp', 'vp' (only for requests that give the sensor's position), each with
    '+up' where another is fitted for requests that give up ('up' alone: only for those) and
    '+upvp' for those that give both, or '-'."""
    kinds = [
        kind
        for kind, has in (("yes", plain), ("vp", viewpoint), ("up", up), ("upvp", up_viewpoint))
        if has
    ]
    return "+".join(kinds) or "-"
