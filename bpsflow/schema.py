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
