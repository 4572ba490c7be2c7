"""The base of every validated schema (config, calibration, diagnosis, truth, intervention).

One rule set for every YAML file bpsflow reads: an unknown key is refused (a typo
never falls back to a default silently), NaN and infinity are refused, and
``true``/``false`` is refused where a number or a name is expected. Pydantic's lax
mode reads ``samples: true`` as 1 and ``lower: false`` as 0.0; a YAML ``yes``,
``on`` or a stray ``true`` in a numeric field is a mistake, never a number.
"""

from __future__ import annotations

import types
import typing
from typing import Any, Union

from pydantic import BaseModel, ConfigDict, model_validator


def _is_model(annotation: Any) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, BaseModel)


def _admits_bool(annotation: Any) -> bool:
    """Whether a field of this type may hold ``true``/``false`` anywhere inside it."""
    if annotation is bool or annotation is Any or _is_model(annotation):
        return True
    if typing.get_origin(annotation) is typing.Literal:
        return any(isinstance(choice, bool) for choice in typing.get_args(annotation))
    if isinstance(annotation, (str, typing.ForwardRef)):   # unresolved: not judged
        return True
    return any(_admits_bool(arg) for arg in typing.get_args(annotation)
               if arg is not Ellipsis)


def _booleans(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    if isinstance(value, dict):
        return any(_booleans(item) for item in value.values())
    if isinstance(value, (list, tuple)):
        return any(_booleans(item) for item in value)
    return False


class StrictModel(BaseModel):
    """Unknown keys, NaN, infinity and booleans in non-boolean fields are validation errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _no_boolean_for_number(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        for name, value in data.items():
            field = cls.model_fields.get(name) if isinstance(name, str) else None
            if field is None or not _booleans(value) or _admits_bool(field.annotation):
                continue
            raise ValueError(f"{name}: expected {_expected(field.annotation)}, got true/false "
                             "(YAML reads yes/no/on/off as true/false too)")
        return data


def _expected(annotation: Any) -> str:
    origin = typing.get_origin(annotation)
    if origin in (Union, types.UnionType):
        names = [_expected(arg) for arg in typing.get_args(annotation)
                 if arg is not type(None)]
        return " or ".join(dict.fromkeys(names))
    if annotation is int:
        return "a whole number"
    if annotation is float:
        return "a number"
    if annotation is str:
        return "text"
    if origin in (list, tuple):
        return "a list of " + "/".join(_expected(arg) for arg in typing.get_args(annotation)
                                       if arg is not Ellipsis)
    if origin is dict:
        args = typing.get_args(annotation)
        return f"a mapping to {_expected(args[1])}" if len(args) == 2 else "a mapping"
    return "a value of another type"


def _type_text(annotation: Any) -> str:
    """A YAML reader's name for a field type: ``number``, ``list of name``, ``a | b``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if annotation is type(None):
        return "null"
    if origin is typing.Annotated:
        return _type_text(args[0])
    if origin is typing.Literal:
        return " | ".join(str(a) for a in args)
    if origin in (Union, types.UnionType):
        parts = [part for a in args for part in _type_text(a).split(" | ")]
        return " | ".join(dict.fromkeys(parts))
    if origin in (list, tuple, set, frozenset):
        return f"list of {_type_text(args[0])}" if args else "list"
    if origin is dict:
        return f"mapping of {_type_text(args[1])}" if len(args) == 2 else "mapping"
    if _is_model(annotation):
        return "section"
    names = {int: "integer", float: "number", str: "text", bool: "true | false", Any: "any"}
    if getattr(annotation, "__name__", "").endswith("Path"):
        return "path"
    return names.get(annotation, getattr(annotation, "__name__", str(annotation)))


def _models_in(annotation: Any) -> list[tuple[str, type[BaseModel]]]:
    """The sections a field holds, each with the suffix its keys get (``[]``, ``.<name>``)."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if _is_model(annotation):
        return [("", annotation)]
    if origin is typing.Annotated:
        return _models_in(args[0])
    if origin in (Union, types.UnionType):
        found = [m for a in args for m in _models_in(a)]
        if len(found) > 1:   # a tagged union (a distribution): each variant under its type
            return [(f"{suffix}({_variant_tag(model)})", model) for suffix, model in found]
        return found
    if origin in (list, tuple, set, frozenset) and args:
        return [(f"[]{suffix}", model) for suffix, model in _models_in(args[0])]
    if origin is dict and len(args) == 2:
        return [(f".<name>{suffix}", model) for suffix, model in _models_in(args[1])]
    return []


def _variant_tag(model: type[BaseModel]) -> str:
    field = model.model_fields.get("type")
    if field is not None and typing.get_origin(field.annotation) is typing.Literal:
        return f"type: {typing.get_args(field.annotation)[0]}"
    return model.__name__


def config_keys(model: type[BaseModel], prefix: str = "") -> list[tuple[str, str, str]]:
    """Every key of a schema, depth first: ``(key path, type, default)``.

    Read from the pydantic models themselves, so the listing is the schema
    the files are validated against (``bpsflow keys``). A section's keys
    follow it; list items are ``key[]``, mapping entries ``key.<name>``, and
    the variants of a tagged union (the distributions) ``key(type: ...)``.
    """
    from pydantic_core import PydanticUndefined

    rows = []
    for name, field in model.model_fields.items():
        if field.exclude:
            continue
        path = f"{prefix}{name}"
        if field.default is not PydanticUndefined:
            default = "null" if field.default is None else repr(field.default)
        elif field.default_factory is not None:
            made = field.default_factory()     # type: ignore[call-arg]
            default = "(its keys' defaults)" if isinstance(made, BaseModel) else repr(made)
        else:
            default = "required"
        rows.append((path, _type_text(field.annotation), default))
        for suffix, inner in _models_in(field.annotation):
            rows += config_keys(inner, f"{path}{suffix}.")
    return rows
