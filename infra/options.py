"""Command-line options derived from a pydantic model: a setting is declared once, as a field, and its option follows.

``model_options(Model, "episodes", "t_max", ...)`` is a click decorator adding one option a field: ``--t-max`` for
``t_max`` (or the name ``names`` gives), its type from the annotation (an integer, a finite number, a choice of a
``Literal``, a flag of a ``bool`` (``--x/--no-x`` when it is on by default), a path, a repeatable option of a tuple or list of strings), its bounds from the
field's ``ge``/``gt``/``le``/``lt``, its default from the field's default (shown), its help from the description.
A field may say more in ``json_schema_extra``: ``{"limit": "episodes"}`` bounds an integer by that resource limit
too (``infra.console.Counted``), ``{"type": "metres"}`` takes a length as ``4``, ``4m`` or ``2.5 m``, ``{"type":
"list"}`` takes a tuple's items as one word, ``a,b`` (``none`` for none; the model's validator splits it). A field
without a default is a required option. The command then builds its model from the options' values
(``settings(Model, values)``: a value the model refuses is a usage error naming its option), so a bound, a default
or a help text is written once, in the model.
"""

from __future__ import annotations

import json
import types
import typing
from collections.abc import Callable
from pathlib import Path

import click
from pydantic import BaseModel, ValidationError
from pydantic.fields import FieldInfo

from uavplace.infra.console import Counted, Finite, Metres
from uavplace.schemas.base import validation_message

M = typing.TypeVar("M", bound=BaseModel)


def field_bounds(info: FieldInfo) -> dict[str, float]:
    """The field's bounds (pydantic's ``ge``, ``gt``, ``le``, ``lt`` constraints) as keyword arguments of click's
    ranges: ``min``/``max``, open where strict."""
    out: dict[str, float] = {}
    for m in info.metadata:
        for name, key, strict in (("ge", "min", False), ("gt", "min", True), ("le", "max", False), ("lt", "max", True)):
            value = getattr(m, name, None)
            if value is not None:
                out[key] = value
                if strict:
                    out[f"{key}_open"] = True
    return out


def _plain(annotation: object) -> object:
    """The annotation without ``None`` (an optional setting's option defaults to None)."""
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType) and type(None) in args:
        rest = [a for a in args if a is not type(None)]
        return rest[0] if len(rest) == 1 else typing.Union[tuple(rest)]  # noqa: UP007 - built from a tuple
    return annotation


def option_kwargs(model: type[BaseModel], field: str, override: dict | None = None) -> dict:
    """click.option's keyword arguments for ``model``'s ``field`` (see the module's docstring), ``override`` replacing
    the derived ones (a ``type`` the annotation does not say)."""
    override = override or {}
    info = model.model_fields[field]
    annotation = _plain(info.annotation)
    extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
    default = info.get_default(call_default_factory=True)
    kwargs: dict = {"help": info.description or "", "default": default, "show_default": default is not None}
    origin = typing.get_origin(annotation)
    bounds = field_bounds(info)
    if info.is_required():
        kwargs.update(required=True, default=None, show_default=False)
    if extra.get("type") == "metres":  # a length: 4, 4m or 2.5 m; its bounds checked by the model
        kwargs["type"] = Metres()
    elif extra.get("type") == "list":  # items given as one word, a,b ('none': no item); the model splits them
        kwargs.update(type=click.STRING, default=",".join(map(str, default)) or "none")
    elif annotation is bool:  # a flag; one on by default is a pair, --x/--no-x (``model_options``)
        kwargs.update(is_flag=True, show_default=bool(default))
    elif annotation is int:
        if "limit" in extra:
            kwargs["type"] = Counted(str(extra["limit"]), min=int(bounds.get("min", 1)))
        else:
            kwargs["type"] = click.IntRange(**{k: int(v) if k in ("min", "max") else v for k, v in bounds.items()})
    elif annotation is float:
        kwargs["type"] = Finite(**bounds)
    elif origin is typing.Literal:
        kwargs["type"] = click.Choice([str(v) for v in typing.get_args(annotation)])
    elif annotation is Path:
        kwargs["type"] = click.Path(path_type=Path)
    elif origin in (tuple, list) and typing.get_args(annotation)[0] is str:
        kwargs.update(multiple=True, default=tuple(default or ()), show_default=False)
    elif annotation is not str and "type" not in override:
        raise TypeError(f"{model.__name__}.{field}: no option type for {annotation!r}: give one ({field}={{'type': ...}})")
    return kwargs | override


class FieldOption(click.Option):
    """An option derived from a model's field (``model_options``): ``field`` names its origin, ``Model.field``."""

    def __init__(self, *args, field: str = "", **kwargs) -> None:  # noqa: ANN002, ANN003 - click.Option's
        super().__init__(*args, **kwargs)
        self.field = field


def model_options(
    model: type[BaseModel],
    *fields: str,
    names: dict[str, str] | None = None,
    unset: dict[str, str] | None = None,
    **overrides: dict,
) -> Callable[[Callable], Callable]:
    """A click decorator: an option for each of ``model``'s ``fields`` (all of them by default), in that order in
    ``--help``; ``names`` maps a field to its option's name where it is not ``--field-name``; ``unset`` maps a field
    to where its value comes from when the option is not given (the option's value is then None, its help says
    ``default: WHERE``: a preset's); ``overrides`` maps a field to click.option keyword arguments that replace the
    derived ones (a type the annotation does not say)."""
    chosen = fields or tuple(model.model_fields)
    names = names or {}
    for field, where in (unset or {}).items():
        help_text = model.model_fields[field].description or ""
        overrides = overrides | {
            field: overrides.get(field, {})
            | {"default": None, "show_default": False, "required": False, "help": f"{help_text.rstrip('.')} (default: {where})."}
        }

    def decorate(command: Callable) -> Callable:
        for field in reversed(chosen):
            flag = names.get(field, "--" + field.replace("_", "-"))
            kwargs = option_kwargs(model, field, overrides.get(field))
            if kwargs.get("is_flag") and kwargs["default"] is True:  # on by default: --x turns it on, --no-x off
                flag = f"{flag}/--no-{flag.removeprefix('--')}"
                del kwargs["is_flag"]
            command = click.option(flag, field, cls=FieldOption, field=f"{model.__name__}.{field}", **kwargs)(command)
        return command

    return decorate


def settings(model: type[M], values: dict, names: dict[str, str] | None = None) -> M:
    """``model`` of a command's option values (those ``model_options`` derived, by field name); a value the model
    refuses (a cross-field check of its validators too) is click's usage error naming the field's option (``names``
    as ``model_options`` took them)."""
    try:
        return model(**values)
    except ValidationError as exc:
        field, message = validation_message(exc)
        top = field.split(".")[0]
        option = (names or {}).get(top, "--" + top.replace("_", "-"))
        hint = f"'{option}'" if top in model.model_fields else None  # as click names an option
        raise click.BadParameter(message, param_hint=hint) from None


def _pair_value(text: str) -> object:
    """A ``NAME=VALUE`` value: JSON where it parses (a number, true, null), else the text itself (a word such as
    hyperbolic); the model converts and checks it."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _kind(annotation: object) -> str:
    return {int: "whole number", float: "number", str: "word"}.get(annotation, "value of this setting")


def with_pairs(config: M, pairs: tuple[str, ...] | list[str], option: str) -> M:
    """``config`` with the fields ``pairs`` name (``NAME=VALUE`` texts, a later one of a name winning) set, checked by
    its model as a whole (a cross-field validator too); a text without ``=``, a name the model lacks or a value it
    refuses is click's usage error naming ``option`` and the model's fields."""
    model = type(config)
    changed: dict[str, object] = {}
    for text in pairs:
        name, sep, value = text.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or name not in model.model_fields:
            fields = ", ".join(model.model_fields)
            raise click.BadParameter(f"{text!r}: expected NAME=VALUE, NAME one of {fields}", param_hint=f"'{option}'")
        changed[name] = _pair_value(value.strip())
        annotation = model.model_fields[name].annotation
        if isinstance(changed[name], bool) and annotation is not bool and bool not in typing.get_args(annotation):  # true: 1
            raise click.BadParameter(f"{name}: {value.strip()} is not a {_kind(annotation)}", param_hint=f"'{option}'")
    try:
        return model(**(config.model_dump() | changed))
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise click.BadParameter(f"{field}: {message}", param_hint=f"'{option}'") from None
