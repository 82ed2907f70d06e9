"""Request and response bodies of the HTTP and WebSocket API (pydantic; they drive /docs).

Frames and units: ``T_canonical_from_input`` is a 4x4 row-major matrix that maps a point ``p`` of
the cloud as sent to ``R p + t`` in the model category's canonical frame; ``translation`` is ``t``
in the input's own units. Quaternions are given in both orders, ``quat_wxyz`` and ``quat_xyzw``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, create_model

from itnet.model_card import ModelCard
from itnet.pose.request import PoseRequest

# fail_fast: a million bad points give one error, not a million.
# Strict: a number (integer or not), never a boolean or a numeric string.
Point = Annotated[
    list[StrictFloat], Field(min_length=3, max_length=3, fail_fast=True, description="[x, y, z]")
]
Matrix4 = Annotated[list[list[float]], Field(description="4x4 row-major rigid transform")]
StopReason = Literal["budget", "max_iterations", "converged", "cancelled"]

EXAMPLE_POINTS = [[0.1, 0.2, 0.3], [0.4, -0.1, 0.2], [-0.3, 0.5, 0.1], [0.0, -0.4, -0.2]]
EXAMPLE_POSE = [[1.0, 0.0, 0.0, -0.05], [0.0, 1.0, 0.0, -0.05], [0.0, 0.0, 1.0, -0.1],
                [0.0, 0.0, 0.0, 1.0]]  # fmt: skip
EXAMPLE_REQUEST: dict[str, Any] = {"points": EXAMPLE_POINTS * 8, "budget_ms": 50, "model": "chair"}


class EstimateRequest(PoseRequest):
    """JSON body of POST /v1/estimate, and the first message of the WebSocket stream."""

    points: list[Point] = Field(
        fail_fast=True, description="the cloud, N x 3, any unit (metres, say)"
    )

    model_config = ConfigDict(json_schema_extra={"examples": [EXAMPLE_REQUEST]})


class StreamRequest(EstimateRequest):
    """The WebSocket's first message: an EstimateRequest, may be tagged ``"type": "estimate"``."""

    type: Literal["estimate"] | None = None


class Pose(BaseModel):
    T_canonical_from_input: Matrix4 = Field(examples=[EXAMPLE_POSE])
    quat_wxyz: list[float] = Field(description="rotation as w, x, y, z", examples=[[1, 0, 0, 0]])
    quat_xyzw: list[float] = Field(description="rotation as x, y, z, w", examples=[[0, 0, 0, 1]])
    translation: list[float] = Field(description="t, input units", examples=[[-0.05, -0.05, -0.1]])


class EstimateOut(Pose):
    """The pose after ``iteration`` steps (iteration 1 is the first network step)."""

    iteration: int
    elapsed_ms: float = Field(description="since the request's run started, milliseconds")
    update_rotation_deg: float = Field(description="rotation of this iteration's update, degrees")
    update_translation: float = Field(description="translation of this update, input units")


class Candidate(BaseModel):
    category: str
    probability: float


class EstimateResponse(Pose):
    """The final pose, how it was reached, and every per-iteration estimate."""

    iterations: int = Field(description="network steps run (0: none fit the budget)")
    stopped_by: StopReason
    elapsed_ms: float = Field(description="engine time for the whole run, milliseconds")
    model: str
    estimates: list[EstimateOut]
    category: str | None = Field(None, description='model "auto" only: the recognised category')
    category_probability: float | None = Field(None, description='"auto": its probability')
    candidates: list[Candidate] | None = Field(None, description='"auto": most probable first')
    unsure: bool | None = Field(
        None, description='"auto": the probability is below the classifier\'s threshold'
    )
    classify_ms: float | None = Field(None, description='"auto": time the classification took')
    ensemble: int = Field(description="runs the pose was estimated with (fused where more than 1)")
    skipped: list[str] = Field(
        default_factory=list,
        description="finishing stages that were on but did not fit the budget left after the "
        "last step (recheck, verify, mirror, centre)",
    )
    mirror: bool | None = Field(
        None,
        description="where the mirror refinement was on: true if the final pose was finished by "
        "it, false if the budget could not hold it (the final pose is then the last estimate)",
    )
    verified: bool | None = Field(
        None,
        description="where verify was on: true if the fused pose was anchored by the run that "
        "sits most firmly in its basin, false if the budget could not hold the probes",
    )
    rechecked: bool | None = Field(
        None,
        description="where recheck was on and the verifier doubted the run: true if the "
        "recheck's runs ran (the pose is the likeliest of all), false if the budget could not "
        "hold them",
    )
    mirror_planes: list[str] | None = Field(
        None,
        description="where the mirror refinement was on: the planes that finished the pose, in "
        "order (fewer than the model's when the budget held only some)",
    )
    centre: bool | None = Field(
        None,
        description="where the centre correction was on: true if it finished the final pose "
        "(false when the run made no step)",
    )
    centre_viewpoint: bool | None = Field(
        None,
        description="where the request gave a viewpoint: true if the correction that goes by "
        "the sensor's direction finished the centre (false: the model has none, or no step ran)",
    )
    centre_up: bool | None = Field(
        None,
        description="where the request gave 'up' and the centre correction was on: true if a "
        "correction fitted on runs held upright finished the centre (with centre_viewpoint: the "
        "one that also goes by the sensor's direction; false: the model has none, a viewpoint "
        "correction fitted on runs not held did it, or no step ran)",
    )
    up: list[float] | None = Field(
        None,
        description="where the request gave 'up': that direction, unit length, in the cloud's "
        "frame; the pose maps it onto the canonical +y",
    )
    runs: list[Matrix4] | None = Field(
        None,
        description="where the request said 'runs': each run's own final T_canonical_from_input "
        "(before fusion and the finishing stages)",
    )


# What the model file keeps to itself: the correction tables, the graph's inputs and outputs,
# the training record and the card's own format. Every other card field is in ModelInfo as the
# card declares it.
CARD_KEPT_IN_FILE = frozenset({
    "kind", "version", "trained_points", "inputs", "outputs", "training", "up_free_steps",
    "centre_correction", "centre_correction_viewpoint", "centre_correction_up",
    "centre_correction_up_viewpoint",
})  # fmt: skip


def _computed_default(kind: Any, description: str | None) -> Any:
    """A card's computed field as a field of the listing: a list is empty by default, anything
    else None."""
    if getattr(kind, "__origin__", None) is list:
        return Field(default_factory=list, description=description)
    return Field(default=None, description=description)


class ServedModel(BaseModel):
    """What this server knows of a loaded model beside its card."""

    model_config = ConfigDict(protected_namespaces=())

    mirror: bool = Field(
        False,
        description="the category has mirror symmetries (mirror_planes): a single run's final "
        "pose is finished by them unless a request says 'mirror': false",
    )
    verifier: str | None = Field(
        None,
        description="the learned verifier of the model's category, where one is loaded: verify "
        "then anchors the fused runs on the run it finds likeliest (one call) instead of the "
        "network's probes",
    )
    centre: bool = Field(
        False,
        description="the model has a centre correction: the final pose's object centre "
        "is finished by it unless a request says 'centre': false",
    )
    centre_viewpoint: bool = Field(
        False,
        description="the model also has a centre correction for requests that give "
        "'viewpoint' (the sensor's position)",
    )
    centre_up: bool = Field(
        False,
        description="the model also has a centre correction fitted on runs held upright, for "
        "requests that give 'up'",
    )
    centre_up_viewpoint: bool = Field(
        False,
        description="the model also has a viewpoint correction fitted on runs held upright, for "
        "requests that give both 'up' and 'viewpoint'",
    )
    step_ms: float = Field(description="measured time of one step on this server, milliseconds")
    default: bool = Field(description="used when a request names no model")


ModelInfo = create_model(
    "ModelInfo",
    __base__=ServedModel,
    __doc__="One loaded model: its card's fields (as the card declares them) and what this "
    "server knows beside it.",
    **{
        name: (spec.annotation, spec)
        for name, spec in ModelCard.model_fields.items()
        if name not in CARD_KEPT_IN_FILE
    },
    **{  # what the card reads from its own fields (its measurements as numbers)
        name: (spec.return_type, _computed_default(spec.return_type, spec.description))
        for name, spec in ModelCard.model_computed_fields.items()
    },
)


class UprightClassifierInfo(BaseModel):
    """The upright classifier: clouds levelled by the request's ``up``, only their yaw free."""

    threshold: float
    accuracy: float
    mean_class_accuracy: float
    evaluation: str
    sizes: str | None = None


class AutoInfo(BaseModel):
    """The category classifier behind ``model: "auto"``."""

    classes: list[str]
    threshold: float = Field(description="below this probability a recognition is unsure")
    accuracy: float = Field(description="top-1 accuracy on partial test views (fraction)")
    mean_class_accuracy: float
    points: int
    evaluation: str
    second_looks: int = Field(
        description="looks in all that a cloud unsure after one gets, where the budget has room "
        "(1: no second opinion; ITNET_CLASSIFY_SECOND_LOOKS)"
    )
    cascade: float | None = Field(
        None,
        description="the graph's cascade: its other heads run only for looks whose first head "
        "is below this probability (null: every head on every look)",
    )
    models: dict[str, str | None] = Field(
        description="the pose model 'auto' runs for each class (null: none loaded)"
    )
    sizes: str | None = Field(
        None,
        description="how the classifier does with the size too, when a request gives its "
        "'units' (null: it has no size prior, and the unit is not used)",
    )
    upright: UprightClassifierInfo | None = Field(
        None,
        description="the classifier for requests that give 'up' (null: none loaded; the up "
        "then does not enter the classification)",
    )


class ModelsResponse(BaseModel):
    models: list[ModelInfo]
    default_model: str | None
    auto: AutoInfo | None = Field(None, description='model "auto" (null: no classifier loaded)')


class Health(BaseModel):
    status: Literal["ok"] = "ok"


class Readiness(BaseModel):
    ready: bool
    models: list[str]
    detail: str | None = None


class ErrorResponse(BaseModel):
    """Every 4xx/5xx body: ``detail`` says what is wrong in one sentence."""

    detail: str = Field(examples=["3 point(s) have NaN or infinite coordinates"])
    kind: str = Field(description="machine-readable error class", examples=["bad_cloud"])
