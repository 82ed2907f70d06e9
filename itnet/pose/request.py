"""``PoseRequest``: the one declaration of what a caller may ask of the pose pipeline.

Every way in uses it: the JSON body and the binary body's query string of ``POST /v1/estimate``,
the WebSocket's first message, ``itnet pose``, alignment, batch, both Python clients and the web
page (tests check that each of them offers every field). Validation is strict: a number is a
JSON number (``"budget_ms": "50"`` and ``"budget_ms": true`` are refused), except in a query
string, where every value is text (``RequestModel.from_query``).

Frames: ``viewpoint`` and ``up`` are in the cloud's own frame (and, for ``viewpoint``, units).
"""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import ConfigDict, Field

from itnet.request_fields import RequestModel, Xyz
from itnet.size_prior import Unit


class PoseRequest(RequestModel):
    """How long, with which model, and with which finishing stages to estimate a pose.

    ``None`` means "the model card's default" for every switch (``ensemble``, ``mirror``,
    ``verify``, ``recheck``, ``centre``): ``itnet.pose.plan`` decides it from the card and the
    rest of the request, the same way for every caller."""

    model_config = ConfigDict(strict=True, extra="forbid", protected_namespaces=())
    # A command line poses files and waits for the best pose: a second, and the chair model by
    # name (``itnet pose``, ``itnet batch pose``).
    CLI_DEFAULTS: ClassVar[dict[str, Any]] = {"budget_ms": 1000.0, "model": "chair"}

    budget_ms: float = Field(
        default=50.0,
        gt=0,
        description="time budget in milliseconds, counted from the request's arrival; the "
        "pipeline runs a step or a stage only where its predicted time still fits",
    )
    max_iterations: int | None = Field(
        default=None, ge=1, description="iteration cap (default: the model's recommended count)"
    )
    model: str | None = Field(
        default=None,
        description="model name, see GET /v1/models (default: 'chair' or the only model); "
        "'auto': classify the cloud, then run its category's model",
    )
    ensemble: int | None = Field(
        default=None,
        ge=1,
        le=16,
        description="runs fused per estimate: K runs from starts turned 360/K degrees about the "
        "cloud's z axis (or about 'up'), each on its own random subset, fused robustly after "
        "every iteration; a step costs about K times as much (default: the model's "
        "recommended_ensemble, halved until its iterations fit budget_ms on an idle server)",
    )
    points_per_run: int | None = Field(
        default=None,
        ge=16,
        le=2048,
        description="the most points each run sees of the cloud (default: the model card's, "
        "the count it was trained on); a step costs about in proportion to them",
    )
    schedule: bool | None = Field(
        default=None,
        description="follow the model card's schedule: the first steps on fewer points, then "
        "only the runs the verifier finds likeliest (the same accuracy for about a third of the "
        "network's work; default: where the card has one); false: every run on all its points "
        "every step",
    )
    mirror: bool | None = Field(
        default=None,
        description="finish the final pose by the category's mirror symmetries (a few "
        "milliseconds; default: where the model's card declares them, for a single run, and "
        "for fused runs where the card says so); true for a model without them is refused",
    )
    verify: bool | None = Field(
        default=None,
        description="with fused runs: anchor the fusion on the run that looks right to the "
        "category's learned verifier (one call), or without one on the run that sits most "
        "firmly in its basin (network probes); default: where the model's card says so; "
        "refused for a single run, and with 'up' where no learned verifier is loaded",
    )
    recheck: bool | None = Field(
        default=None,
        description="a single run that the category's learned verifier doubts gets a second "
        "opinion: a few runs from turned starts, and the likeliest answer of all (default: "
        "where the model's card says so); refused without a verifier, with fused runs or 'up'",
    )
    centre: bool | None = Field(
        default=None,
        description="finish the final pose's object centre by the model's centre correction "
        "(a fraction of a millisecond; default: where the model has one); true for a model "
        "without one is refused",
    )
    viewpoint: Xyz = Field(
        default=None,
        description="where the sensor was, [x, y, z] in the cloud's frame and units ('x,y,z' in "
        "a query): [0, 0, 0] for a depth camera's cloud in its own frame; the centre correction "
        "then goes by the direction toward the sensor, where the model has that correction",
    )
    up: Xyz = Field(
        default=None,
        description="which way is up in the cloud, [x, y, z] (against gravity: an IMU's or a "
        "floor's normal; 'x,y,z' in a query): the pose is held upright, its canonical +y on "
        "this direction, and only the turn about it and the position are estimated",
    )
    runs: bool = Field(
        default=False,
        description="also reply with each run's own final pose ('runs': T_canonical_from_input "
        "of every run, before fusion and finishing): the alternatives alignment weighs",
    )
    strip: bool | None = Field(
        default=None,
        description="take away the floor under the object and the walls behind it that a "
        "cut-out kept (an object cut out of a depth frame or a room by its box), before it is "
        "classified and posed: level and upright planes at its edge that run on past the "
        "object, seen from the 'viewpoint' (or the origin, where the cloud is one view from "
        "it); needs 'up' (default: where 'up' is given); the reply says how many points went",
    )
    units: Unit | None = Field(
        default=None,
        description="the cloud's unit, if known: with model 'auto' the cloud's size then counts "
        "toward its category as well as its form; the pose does not depend on it",
    )


REQUEST_FIELDS: tuple[str, ...] = tuple(PoseRequest.model_fields)
