"""What every request type shares: the one ``x,y,z`` parser, the ``Xyz`` field type, and how a
request reads and writes a query string.

A request type (``PoseRequest``, ``AlignRequest``, ``SceneRequest``) declares each field once,
with its default, its limits and its description; the typer options
(``itnet.commands.request_options``), the FastAPI query parameters (:func:`query_parameters`),
the clients' keyword arguments and the page's controls are derived from those declarations.

    parse_xyz("0,-1,0")                  # [0.0, -1.0, 0.0]
    PoseRequest.from_query({"budget_ms": "20", "up": "0,-1,0"})
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike
from pydantic import BaseModel, Field

# Three numbers, [x, y, z] in JSON and Python; 'x,y,z' on a command line and in a query string.
Xyz = Annotated[list[float], Field(min_length=3, max_length=3)] | None

Request = TypeVar("Request", bound="RequestModel")


def parse_xyz(value: str | ArrayLike) -> list[float]:
    """'x,y,z', or any three numbers (a list, a tuple, an array of shape (3,)) -> [x, y, z].
    ValueError unless there are exactly three finite numbers."""
    try:
        if isinstance(value, str):
            numbers = [float(v) for v in value.split(",")]
        else:
            numbers = [float(v) for v in np.asarray(value, dtype=np.float64).reshape(-1)]
    except (TypeError, ValueError):
        numbers = []
    if len(numbers) != 3 or not all(math.isfinite(v) for v in numbers):
        raise ValueError(f"expected three numbers 'x,y,z', each finite, got {value!r}")
    return numbers


def parse_pair(text: str) -> tuple[int, int]:
    """'A,B' -> (A, B), two positive integers (a schedule's steps and points, a halving's
    iteration and runs kept). ValueError for anything else."""
    values = text.split(",")
    if len(values) != 2 or not all(v.strip().isdigit() and int(v) >= 1 for v in values):
        raise ValueError(f"expected two positive integers 'A,B', got {text!r}")
    return int(values[0]), int(values[1])


def is_xyz(annotation: Any) -> bool:
    """Whether a field's annotation is ``Xyz`` (three numbers or None)."""
    return annotation == Xyz


class RequestModel(BaseModel):
    """A request type: its fields, and their text form in a query string."""

    @classmethod
    def from_query(cls: type[Request], query: Mapping[str, str]) -> Request:
        """A query string's fields (every value text: '50', 'true', '0,-1,0') -> the request.
        Raises pydantic.ValidationError (an 'x,y,z' that is not three numbers included)."""
        fields: dict[str, Any] = dict(query)
        xyz: dict[str, Any] = {}
        for name, spec in cls.model_fields.items():
            if name in fields and is_xyz(spec.annotation):
                text = fields.pop(name)
                try:
                    xyz[name] = parse_xyz(text)
                except ValueError:
                    xyz[name] = text  # the validation below says why it is refused
        strings = cls.model_validate_strings(fields).model_dump(exclude_unset=True)
        return cls.model_validate({**strings, **xyz})

    def to_query(self) -> dict[str, str]:
        """The fields set to other than their default, as a query string's values (the inverse
        of :meth:`from_query`)."""
        out = {}
        for name, value in self.model_dump(exclude_defaults=True).items():
            if isinstance(value, bool):
                out[name] = "true" if value else "false"
            elif isinstance(value, list):
                out[name] = ",".join(f"{float(v):.9g}" for v in value)
            else:
                out[name] = str(value)
        return out

    @classmethod
    def field_help(cls, name: str) -> str:
        """A field's description as a help text: capitalised, with a full stop."""
        description = cls.model_fields[name].description or ""
        return description[:1].upper() + description[1:] + "." if description else ""


def query_parameters(kind: type[RequestModel], note: str = "") -> list[dict[str, Any]]:
    """A request type's fields as OpenAPI query parameters: each field's JSON schema without its
    null branch, three numbers as the string 'x,y,z'; ``note`` goes before each description."""
    out = []
    for name, field in kind.model_json_schema()["properties"].items():
        branches = [b for b in field.get("anyOf", [field]) if b.get("type") != "null"]
        schema = {k: v for k, v in branches[0].items() if k not in ("title", "description")}
        if schema.get("type") == "array":
            schema = {"type": "string", "pattern": r"^[^,]+,[^,]+,[^,]+$"}
        if field.get("default") is not None:
            schema["default"] = field["default"]
        out.append({"name": name, "in": "query", "required": False, "schema": schema,
                    "description": f"{note}{field.get('description', '')}"})  # fmt: skip
    return out
