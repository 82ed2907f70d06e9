"""A command's options derived from a request type: one typer option per field, with the field's
default, limits and description, so a field is declared once (in its request type) and every
command that takes the request offers it.

    @request_options(PoseRequest)
    def pose(files: list[Path] = typer.Argument(...), request: PoseRequest = ...) -> None:
        ...  # the command gets the validated PoseRequest

Per field: ``--name`` (``--name/--no-name`` for switches), 'x,y,z' text for three numbers,
``min``/``max`` from the field's ``ge``/``le``. A request type may declare, beside its fields,
``CLI_DEFAULTS`` (a command line's own default for a field, e.g. a longer budget for a file)
and ``CLI_ALIASES`` (more names for an option). A value the request refuses is a usage error
naming the option (exit 2).
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Literal, TypeVar, get_args, get_origin

import annotated_types
import typer
from pydantic import BaseModel, ValidationError

from itnet.request_fields import is_xyz, parse_xyz

Command = TypeVar("Command", bound=Callable[..., Any])
# The default of a command's request parameter: ``request_options`` puts the request's own
# options in its place, so typer never sees it.
REQUEST: Any = None


def cli_defaults(kind: type[BaseModel]) -> Mapping[str, Any]:
    """The command line's own defaults of ``kind`` (field name -> value)."""
    return getattr(kind, "CLI_DEFAULTS", {})


def xyz_option(value: str | None) -> list[float] | None:
    """typer callback: 'x,y,z' -> [x, y, z], or a usage error."""
    if value is None:
        return None
    try:
        return parse_xyz(value)
    except ValueError as err:
        raise typer.BadParameter(str(err)) from None


def _limits(metadata: Iterable[Any]) -> dict[str, Any]:
    """A field's ``ge``/``le`` as typer's ``min``/``max`` (``gt``/``lt`` are the request's to
    check)."""
    out: dict[str, Any] = {}
    for item in metadata:
        if isinstance(item, annotated_types.Ge):
            out["min"] = item.ge
        elif isinstance(item, annotated_types.Le):
            out["max"] = item.le
    return out


def option(kind: type[BaseModel], name: str) -> inspect.Parameter:
    """The typer option of ``kind``'s field ``name``."""
    spec = kind.model_fields[name]
    default = cli_defaults(kind).get(name, spec.default)
    flag = "--" + name.replace("_", "-")
    aliases = tuple(getattr(kind, "CLI_ALIASES", {}).get(name, ()))
    description = spec.description or ""
    settings: dict[str, Any] = {
        "help": description[:1].upper() + description[1:] + "." if description else None
    }
    annotation: Any = spec.annotation
    if is_xyz(annotation):
        annotation, settings["callback"] = (str | None), xyz_option
    elif annotation in (bool, bool | None):
        flag = f"{flag}/--no-{name.replace('_', '-')}"
    elif any(get_origin(a) is Literal for a in (annotation, *get_args(annotation))):
        annotation = str | None if default is None else str  # the request checks the choice
    else:
        settings.update(_limits(spec.metadata))
    if default is None:
        settings["show_default"] = False
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, annotation=annotation,
                             default=typer.Option(default, flag, *aliases, **settings))  # fmt: skip


def build_request(kind: type[BaseModel], values: Mapping[str, Any]) -> Any:
    """The options' values -> a request of ``kind``, or a usage error naming the option (exit 2)."""
    try:
        return kind.model_validate(dict(values), strict=False)
    except ValidationError as err:
        first = err.errors(include_url=False)[0]
        name = "--" + str(first["loc"][0]).replace("_", "-") if first["loc"] else "options"
        typer.echo(f"error: {name}: {first['msg']}", err=True)
        raise typer.Exit(2) from None


def request_options(
    kind: type[BaseModel], into: str = "request", skip: Iterable[str] = ()
) -> Callable[[Command], Command]:
    """Decorate a typer command whose parameter ``into`` takes a ``kind``: the command offers one
    option per field of ``kind`` (but ``skip``) in its place and gets the validated request."""
    skipped = set(skip)
    fields = [name for name in kind.model_fields if name not in skipped]

    def wrap(command: Command) -> Command:
        own = inspect.signature(command, eval_str=True)
        kept = [p for p in own.parameters.values() if p.name != into]
        clash = {p.name for p in kept} & set(fields)
        if clash:
            raise TypeError(f"{command.__name__} declares request fields itself: {clash}")
        generated = [option(kind, name) for name in fields]

        @functools.wraps(command)
        def run(**given: Any) -> Any:
            values = {name: given.pop(name) for name in fields}
            return command(**given, **{into: build_request(kind, values)})

        parameters = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in kept] + generated
        run.__signature__ = own.replace(parameters=parameters)  # type: ignore[attr-defined]
        run.__annotations__ = {p.name: p.annotation for p in parameters}
        del run.__wrapped__  # typer reads the signature above, not the command's own
        return run  # type: ignore[return-value]

    return wrap
