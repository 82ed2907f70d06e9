"""What a shipped model file says about itself (stored as JSON in the ONNX metadata, key 'itnet').

Shared by the exporter (writes it) and the runtime (reads it), so both agree on the fields.
"""

from __future__ import annotations

import contextlib
from typing import Literal

from pydantic import BaseModel, Field, computed_field

from itnet.measurements import FUSED_KINDS, KINDS, AnytimeProtocol, Kind, Measurement, ViewResult

METADATA_KEY = "itnet"
NORMALIZATION = "centroid, RMS radius (itnet.preprocess)"


class ModelCard(BaseModel):
    """Metadata of one exported IT-Net step."""

    kind: Literal["pose"] = Field("pose", description="a pose step ('classifier': ClassifierCard)")
    name: str = Field(description="model name used in requests, e.g. 'chair'")
    category: str
    version: str = "1"
    precision: str = Field(
        "float32", description="'float32', or 'int8' (per-point layers dynamically quantised)"
    )
    points: int = Field(
        1024, description="points the runtime subsamples a larger cloud to (a smaller one: whole)"
    )
    trained_points: int = 256
    trained_iterations: int = 5
    recommended_iterations: int = 10
    recommended_ensemble: int = Field(
        1,
        ge=1,
        le=16,
        description="runs fused per estimate when a request does not say (the ensemble mode): "
        "more than 1 where a single run falls short of the bar and K runs fused, measured "
        "within the default budget_ms, do not (ensemble_evaluation says how)",
    )
    normalization: str = NORMALIZATION
    canonical_frame: str = "+y up, front toward -z, origin at the bounding-box centre"
    symmetry: Literal["none", "yaw180", "yaw90", "yaw"] = Field(
        "none",
        description="rotations about +y (up) that leave the category's shapes alike: 'none', "
        "'yaw180' (C2), 'yaw90' (C4) or 'yaw' (any turn: round objects); a pose is correct when "
        "any equivalent pose is",
    )
    mirror_planes: list[Literal["x", "z"]] = Field(
        default_factory=list,
        description="canonical planes the category's shapes are mirror-symmetric about: 'x' "
        "(x = 0, left-right), 'z' (z = 0, front-back); the runtime finishes a single run's pose "
        "by them (itnet.mirror) unless the request says not to",
    )
    mirror_evaluation: str = Field(
        "", description="the mirror planes' measured effect as served: one run without and with"
    )
    mirror_fused: bool = Field(
        False,
        description="finish the fused pose of several runs (the ensemble mode) by the mirror "
        "planes too, by default (a single run's always is): chosen per category on validation",
    )
    verify_fused: bool = Field(
        False,
        description="anchor the fusion of several runs (the ensemble mode) by the run that sits "
        "most firmly in its basin (itnet.basin), by default, where the budget holds its probes: "
        "chosen per category on validation",
    )
    recheck_runs: int = Field(
        0,
        ge=0,
        le=16,
        description="a single run that the category's learned verifier doubts is rechecked "
        "with this many runs from turned starts, by default, where the budget holds them "
        "(0: not by default; chosen per category on validation)",
    )
    recheck_evaluation: str = Field(
        "", description="the recheck's measured effect as served: one run without and with it"
    )
    verify_evaluation: str = Field(
        "", description="verify's measured effect as served: fused runs without and with it"
    )
    centre_correction: dict | None = Field(
        None,
        description="a linear correction of the object centre, applied after the last step "
        "(itnet.centre.CentreCorrection; fitted on training shapes by itnet centre-fit)",
    )
    centre_correction_viewpoint: dict | None = Field(
        None,
        description="the same with the sensor's direction as well, for requests that give the "
        "sensor's position (viewpoint)",
    )
    centre_correction_up: dict | None = Field(
        None,
        description="the same fitted on runs held upright, for requests that give the up "
        "direction (and no viewpoint the card has a correction for): itnet centre-fit --up",
    )
    centre_correction_up_viewpoint: dict | None = Field(
        None,
        description="the viewpoint correction fitted on runs held upright, for requests that "
        "give both the up direction and the sensor's position (a camera's cloud with its "
        "gravity, a scene's object): itnet centre-fit --up",
    )
    centre_evaluation: str = Field(
        "", description="the centre correction's measured effect as served: without and with"
    )
    centre_up_evaluation: str = Field(
        "",
        description="centre_correction_up's (and centre_correction_up_viewpoint's) measured "
        "effect, as served with the up direction",
    )
    requires_up: bool = Field(
        False,
        description="the model is measured, and served, only with the up direction given: a "
        "request without 'up' is refused (a category whose partial views leave its tilt "
        "ambiguous: a box on its side)",
    )
    up_evaluation: str = Field(
        "", description="how the model does with the up direction given, as served"
    )
    up_free_steps: int = Field(
        0,
        ge=0,
        description="with the up direction given, the first this many steps run free (from the "
        "usual starts) and only the later ones, and the final pose, are held upright: for a "
        "category whose network passes through tilted poses on its way to the right one",
    )
    inputs: dict[str, str] = {
        "points": "float32 [B, N, 3], normalised cloud",
        "pose": "float32 [B, 4, 4], pose so far (normalised frame)",
    }
    outputs: dict[str, str] = {
        "pose_next": "float32 [B, 4, 4], update @ pose",
        "delta": "float32 [B, 4, 4], this step's update",
    }
    accuracy: dict[str, float] = Field(
        default_factory=dict,
        description="measured accuracy at (10 deg, 0.1 radius) by iteration count, e.g. {'10': 0.7}",
    )
    evaluation: str = ""
    coarse_steps: tuple[int, int] | None = Field(
        None,
        description="(ITERATIONS, POINTS): the served schedule's first ITERATIONS steps see at "
        "most POINTS of each run's points (a step costs about linearly in runs x points), the "
        "later ones all of them; chosen per category on validation (plan_evaluation says how); "
        "none: every step on all the points",
    )
    halving: tuple[int, int] | None = Field(
        None,
        description="(AT, KEEP): the served schedule's successive halving of fused runs: after "
        "AT iterations only the KEEP runs the category's verifier finds likeliest go on (where "
        "the budget holds its call); none: every run to the end",
    )
    plan_evaluation: str = Field(
        "",
        description="coarse_steps and halving as served against every run on all its points "
        "every step: paired accuracy and the run-point-steps each takes",
    )
    ensemble_evaluation: str = Field(
        "", description="the recommended ensemble against one run, where it is more than 1"
    )
    training: dict[str, object] = Field(default_factory=dict)

    @computed_field(  # type: ignore[prop-decorator]
        description="the figures of the evaluation lines (ensemble, up, mirror, recheck, "
        "verify) as numbers with their protocol: split, budget, machine, and per kind of views "
        "the scans, the accuracy and the accuracy without, with standard errors; read from the "
        "lines, which they render back exactly (a line of another shape has none)"
    )
    @property
    def measurements(self) -> list[Measurement]:
        measured = []
        for kind in KINDS:
            line = getattr(self, f"{kind}_evaluation")
            if line:
                with contextlib.suppress(ValueError):
                    measured.append(Measurement.parse(kind, line))
        return measured

    @computed_field(  # type: ignore[prop-decorator]
        description="how the per-iteration accuracy was measured, read from the evaluation "
        "line: scans, views a shape, view rule, the up's error, split, points (null: a line of "
        "another shape)"
    )
    @property
    def accuracy_protocol(self) -> AnytimeProtocol | None:
        try:
            return AnytimeProtocol.parse(self.evaluation)
        except ValueError:
            return None

    def measurement(self, kind: Kind) -> Measurement | None:
        """The card's measurement of ``kind`` (None where it has none)."""
        return next((m for m in self.measurements if m.kind == kind), None)

    @property
    def mirror(self) -> bool:
        """Whether the category has a mirror symmetry the runtime can finish poses by."""
        return bool(self.mirror_planes)


class SizePrior(BaseModel):
    """How big each class's clouds are, for callers who know their cloud's unit
    (``itnet.size_prior``): per class, a Student-t over the log of a partial view's RMS radius
    about its centroid (the scale ``itnet.preprocess`` divides by) in metres."""

    measure: str = "log of the cloud's RMS radius about its centroid, metres"
    log_median: list[float] = Field(description="per class, in the order of the card's classes")
    log_scale: list[float] = Field(
        description="per class: a robust spread (1.4826 x MAD) of the log"
    )
    df: float = Field(3.0, description="Student-t degrees of freedom: heavy tails, so an odd size "
                      "weighs little")  # fmt: skip
    weight: float = Field(0.5, description="the size's log-likelihood is added times this")
    source: str = ""  # where the sizes came from (data, unit assumed, views)
    evaluation: str = ""  # top-1 with and without it, and on which views


class ClassifierCard(BaseModel):
    """Metadata of an exported category classifier (``model: "auto"``): one graph, normalised
    points [B, N, 3] -> class probabilities [B, C] (the canonicaliser's steps included)."""

    kind: Literal["classifier"] = "classifier"
    name: str = "classifier"
    version: str = "1"
    classes: list[str] = Field(description="category of each output, in order")
    precision: str = "float32"
    points: int = Field(
        256, description="points the runtime subsamples a larger cloud to (a smaller one: whole)"
    )
    normalization: str = NORMALIZATION
    transformer: str = Field("itnet-2", description="the canonicaliser in front of the classifier")
    head: str = Field(
        "pointnet",
        description="the classifier behind the canonicaliser: pointnet (one max-pool over the "
        "cloud) or local (each layer mixes in every point's nearest neighbours)",
    )
    canonical_points: int | None = Field(
        None,
        ge=1,
        description="the canonicaliser finds the pose from the first this many input points "
        "(the runtime feeds them in random order), the classifier then sees them all; "
        "None: the canonicaliser sees every point",
    )
    cascade: float | None = Field(
        None,
        description="a fused graph's cascade: the heads after the first run only for looks "
        "whose first-head top probability is below this, the others get the first head's "
        "answer (export/cascade.py); None: every head on every look",
    )
    threshold: float = Field(
        0.5, description="below this top probability a recognition is reported as unsure"
    )
    accuracy: float = Field(0.0, description="top-1 accuracy on the test views (fraction)")
    mean_class_accuracy: float = 0.0
    evaluation: str = ""
    inputs: dict[str, str] = {"points": "float32 [B, N, 3], normalised cloud"}
    outputs: dict[str, str] = {"probabilities": "float32 [B, C], softmax over classes"}
    training: dict[str, object] = Field(default_factory=dict)
    size_prior: SizePrior | None = Field(
        None, description="class sizes, used when a request gives its cloud's unit"
    )
    upright: bool = Field(
        False,
        description="trained on views levelled by their up direction (only yaw free): serves "
        "requests that say which way is up, beside the classifier for any orientation",
    )


class VerifierCard(BaseModel):
    """Metadata of an exported verifier (``model/verifier.py``): one graph, a run's points where
    its pose puts them, normalised canonical frame [B, N, 3] -> the logit of the pose being
    right [B]. Served beside the pose models of its category: their fused runs' ``verify``
    anchors on the run it finds likeliest."""

    kind: Literal["verifier"] = "verifier"
    name: str
    version: str = "1"
    category: str
    precision: str = "float32"
    points: int = Field(256, description="points of a run it was trained to see")
    trained_on: str = Field("", description="the pose model whose runs it learned from")
    evaluation: str = ""
    training: dict[str, object] = Field(default_factory=dict)


def parse_card(text: str) -> ModelCard | ClassifierCard | VerifierCard:
    """The card stored in a model file (JSON): a classifier's or a verifier's when its kind says
    so, else a pose step's (cards written before ``kind`` existed are pose steps). Raises pydantic's
    ValidationError (a ValueError) for a corrupt card."""
    import json

    try:
        kind = json.loads(text).get("kind", "pose")
    except (ValueError, AttributeError):
        kind = "pose"  # let the pose card's validation say what is wrong
    if kind == "classifier":
        return ClassifierCard.model_validate_json(text)
    if kind == "verifier":
        return VerifierCard.model_validate_json(text)
    return ModelCard.model_validate_json(text)


def describe_anytime(report: dict) -> tuple[dict[str, float], str]:
    """An ``itnet eval`` report.json -> (the card's ``accuracy`` per iteration, its
    ``evaluation``: ``AnytimeProtocol``'s text)."""
    accuracy = {str(k): v for k, v in zip(report["iterations"], report["accuracy"], strict=True)}
    protocol = AnytimeProtocol(scans=report["scans"], views=report["views"],
                               scanner=report.get("scanner", "occluded"),
                               up_error_deg=report.get("up_error_deg"),
                               category=report["category"], points=report["points"])  # fmt: skip
    return accuracy, protocol.text()


def _kinds_measuring(report: dict, k: int) -> list[str]:
    """The kinds of view (occluded, paper, ...) a ``benchmarks.bench_ensemble`` JSON measured
    with K runs; ValueError where none."""
    kinds = [name for name, rows in report.items() if isinstance(rows, dict) and str(k) in rows]
    if not kinds:
        raise ValueError(f"the report does not measure {k} runs")
    return kinds


def ensemble_measurement(report: dict, k: int) -> Measurement:
    """``benchmarks.bench_ensemble``'s JSON -> the measurement of K runs against one on each kind
    of view it measured. Raises KeyError/ValueError where the report lacks K or a single run."""
    if k < 2:
        raise ValueError(f"an ensemble is more than one run, got {k}")
    results = []
    for kind in _kinds_measuring(report, k):
        one, many = report[kind]["1"], report[kind][str(k)]
        results.append(ViewResult(views=kind, runs=k, scans=many["scans"],
                                  accuracy=many["accuracy"], before=one["accuracy"],
                                  gain=many["gain"], gain_stderr=many["gain_stderr"]))  # fmt: skip
    return Measurement(kind="ensemble", split=report["split"], budget_ms=report["budget_ms"],
                       machine=report["machine"], results=results)  # fmt: skip


def describe_ensemble(report: dict, k: int) -> str:
    """The card's ``ensemble_evaluation`` line (``ensemble_measurement``'s text)."""
    return ensemble_measurement(report, k).text()


def up_measurement(report: dict, k: int) -> Measurement:
    """``benchmarks.bench_ensemble``'s JSON of a run with ``--up`` -> the measurement of K runs
    (the card's default) on each kind of view it measured, the up direction given with the
    report's error. Raises ValueError where the report was not made with the up direction or
    lacks K."""
    error = report.get("up_error_deg")
    if error is None:
        raise ValueError("the report was made without --up")
    results = [
        ViewResult(
            views=kind,
            runs=k,
            scans=report[kind][str(k)]["scans"],
            accuracy=report[kind][str(k)]["accuracy"],
            stderr=report[kind][str(k)]["stderr"],
        )
        for kind in _kinds_measuring(report, k)
    ]
    return Measurement(kind="up", split=report["split"], budget_ms=report["budget_ms"],
                       machine=report["machine"], up_error_deg=error, results=results)  # fmt: skip


def describe_up(report: dict, k: int) -> str:
    """The card's ``up_evaluation`` line (``up_measurement``'s text)."""
    return up_measurement(report, k).text()


def _paired_rows(without: dict, with_it: dict,
                 fused: bool | None) -> list[tuple[str, str, dict, dict]]:  # fmt: skip
    """(kind, runs, row without, row with) of two ``benchmarks.bench_ensemble`` JSONs of the
    same views: the one-run rows, or (``fused``) those of more than one run, or (None) every
    row. Raises ValueError where they share none or measured different scans."""
    pairs = []
    for kind, rows in with_it.items():
        if not isinstance(rows, dict) or not isinstance(without.get(kind), dict):
            continue
        for runs, row in rows.items():
            if not runs.isdigit() or runs not in without[kind]:
                continue
            if fused is not None and (int(runs) > 1) != fused:
                continue
            plain = without[kind][runs]
            if plain["scans"] != row["scans"] or without.get("split") != with_it.get("split"):
                raise ValueError(f"{kind}: the two reports measured different scans")
            pairs.append((kind, runs, plain, row))
    if not pairs:
        many = {True: "more than one run", False: "one run", None: "any runs"}[fused]
        raise ValueError(f"the reports share no kind of view measured with {many}")
    return pairs


def switch_measurement(without: dict, with_it: dict, kind: Kind) -> Measurement:
    """A finishing stage the engine can switch on or off (``kind``: mirror, recheck, verify),
    from two ``benchmarks.bench_ensemble`` JSONs of the same views without and with it: each
    kind of view's accuracy before and after, with the paired gain where the second was
    measured against the first (``--baseline``) and the share of scans the stage got to (plan:
    the share of the network's work, points stepped, the schedule took); one run's rows, or
    (verify, plan) those of more. Raises ValueError where they share no such
    measurement or measured different scans."""
    # a schedule is measured on the card's runs, however many
    fused: bool | None = None if kind == "plan" else kind in FUSED_KINDS
    share_key = {"mirror": "mirror_finished", "recheck": "rechecked", "verify": "verified",
                 "plan": "mean_point_steps"}[kind]  # fmt: skip
    results = []
    for views, runs, plain, row in _paired_rows(without, with_it, fused):
        paired = row.get("versus_baseline") or {}
        done = row.get(share_key)
        if kind == "plan":  # the plan's share: its network work over every step's
            done = done / plain[share_key] if done and plain.get(share_key) else None
        results.append(ViewResult(views=views, runs=int(runs), scans=row["scans"],
                                  accuracy=row["accuracy"], before=plain["accuracy"],
                                  gain=paired.get("gain"), gain_stderr=paired.get("gain_stderr"),
                                  share=None if done is None else 100 * done))  # fmt: skip
    return Measurement(kind=kind, split=with_it["split"], budget_ms=with_it["budget_ms"],
                       machine=with_it["machine"], results=results)  # fmt: skip


def describe_mirror(without: dict, with_planes: dict) -> str:
    """The card's ``mirror_evaluation``: one run without and with its mirror planes."""
    return switch_measurement(without, with_planes, "mirror").text()


def describe_recheck(without: dict, with_recheck: dict) -> str:
    """The card's ``recheck_evaluation``: one run without and with the recheck."""
    return switch_measurement(without, with_recheck, "recheck").text()


def describe_verify(without: dict, with_verify: dict) -> str:
    """The card's ``verify_evaluation``: fused runs without and with verify."""
    return switch_measurement(without, with_verify, "verify").text()


def describe_plan(full: dict, planned: dict) -> str:
    """The card's ``plan_evaluation``: fused runs on all their points every step (``full``)
    and with the card's coarse first steps and halving (``planned``)."""
    return switch_measurement(full, planned, "plan").text()
