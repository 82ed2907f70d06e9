"""``PoseRequest``: the one declaration of what a caller may ask of the pose pipeline.

Every way in uses it: the JSON body and the binary body's query string of ``POST /v1/estimate``,
the WebSocket's first message, ``itnet pose``, alignment, batch, both Python clients and the web
page (tests check that each of them offers every field). Validation is strict: a number is a
JSON number (``"budget_ms": "50"`` and ``"budget_ms": true`` are refused), except in a query
string, where every value is text (:meth:`PoseRequest.from_query`).

Frames: ``viewpoint`` and ``up`` are in the cloud's own frame (and, for ``viewpoint``, units).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field

from itnet.size_prior import Unit

# Three numbers, [x, y, z] in JSON; 'x,y,z' in a query string (PoseRequest.from_query).
Xyz = Annotated[list[float], Field(min_length=3, max_length=3)] | None
XYZ_FIELDS = ("viewpoint", "up")


def _numbers(text: str) -> list[float] | str:
    """'0,-1,0' -> [0.0, -1.0, 0.0]; text that is not numbers as it is (validation says why)."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        return text


class PoseRequest(BaseModel):
    """How long, with which model, and with which finishing stages to estimate a pose.

    ``None`` means "the model card's default" for every switch (``ensemble``, ``mirror``,
    ``verify``, ``recheck``, ``centre``): ``itnet.pose.plan`` decides it from the card and the
    rest of the request, the same way for every caller."""

    model_config = ConfigDict(strict=True, extra="forbid", protected_namespaces=())

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
    units: Unit | None = Field(
        default=None,
        description="the cloud's unit, if known: with model 'auto' the cloud's size then counts "
        "toward its category as well as its form; the pose does not depend on it",
    )

    @classmethod
    def from_query(cls, query: Mapping[str, str]) -> PoseRequest:
        """A query string's fields (every value text: '50', 'true', '0,-1,0') -> PoseRequest.
        Raises pydantic.ValidationError."""
        fields: dict[str, Any] = dict(query)
        xyz = {k: _numbers(fields.pop(k)) for k in XYZ_FIELDS if k in fields}
        return cls.model_validate({**cls.model_validate_strings(fields).options(), **xyz})

    def to_query(self) -> dict[str, str]:
        """The fields set to other than their default, as a query string's values (the binary
        body's parameters; the inverse of :meth:`from_query`)."""
        out = {}
        for name, value in self.model_dump(exclude_defaults=True).items():
            if isinstance(value, bool):
                out[name] = "true" if value else "false"
            elif isinstance(value, list):
                out[name] = ",".join(f"{float(v):.9g}" for v in value)
            else:
                out[name] = str(value)
        return out

    def options(self) -> dict[str, Any]:
        """The fields set to other than their default (a reply's or a log's view of it)."""
        return self.model_dump(exclude_defaults=True)


def field_help(name: str) -> str:
    """A field's description, for the help texts of the CLI and the clients."""
    description = PoseRequest.model_fields[name].description
    return description[0].upper() + description[1:] + "." if description else ""


REQUEST_FIELDS: tuple[str, ...] = tuple(PoseRequest.model_fields)
