"""How a parameter's value reaches its targets: shared by both backends.

A parameter targets IDF fields (object type, object name, ``*`` or a
shell-style pattern such as ``Office*``, field
name as in the IDD, compared without case, spaces or punctuation), weather
quantities or boundary samplers (see :mod:`bpsflow.config`). Its ``mode``
says how a sampled value combines with the model's nominal value.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, TypeVar

from bpsflow.simulation.idf import normalise

if TYPE_CHECKING:
    from bpsflow.config import IdfTarget

__all__ = ["TOOL_OBJECT_PREFIX", "apply_mode", "normalise", "matches_name", "select_objects",
           "targets_field"]

T = TypeVar("T")


def apply_mode(mode: str, nominal: float, value: float) -> float:
    """The field value for a sampled ``value``: replace (absolute), multiply (relative) or add."""
    if mode == "relative":
        return nominal * value
    if mode == "additive":
        return nominal + value
    return value


#: Prefix of every object name bpsflow adds to a model (diagnose's extensions, hidden effects).
TOOL_OBJECT_PREFIX = "bpsflow_"


def matches_name(pattern: str, name: str) -> bool:
    """Whether a target's object name selects ``name`` (no case).

    ``*`` selects every object of the model; a name with ``*`` or ``?`` is a
    shell-style pattern (``Office*`` selects ``Office`` and ``Office 07``);
    any other name selects that object alone. A pattern never selects the
    objects bpsflow adds (names starting :data:`TOOL_OBJECT_PREFIX`, e.g. the
    infiltration diagnose fits) unless it starts with that prefix itself: a
    user's ``*`` means the model's objects, and scaling an added object's
    fitted value (or its empty fields) would change what diagnose measures.
    """
    wanted, name = pattern.strip().upper(), name.strip().upper()
    if "*" in wanted or "?" in wanted:
        prefix = TOOL_OBJECT_PREFIX.upper()
        if name.startswith(prefix) and not wanted.startswith(prefix):
            return False
        return wanted == "*" or fnmatch.fnmatchcase(name, wanted.replace("[", "[[]"))
    return wanted == name


def select_objects(objects: Sequence[T], pattern: str,
                   name_of: Callable[[T], str] = lambda obj: obj.name) -> list[T]:  # type: ignore[attr-defined]
    """The objects a target's name selects: all for ``*``, else those of that name (no case).

    ``name_of`` reads an object's name (the no-IDD reader's ``.name`` by
    default; the EnergyPlus backend passes eppy's).
    """
    return [obj for obj in objects if matches_name(pattern, name_of(obj))]


def targets_field(target: IdfTarget, object_type: str, field: str,
                  name: str | None = None) -> bool:
    """Whether an IDF target sets ``field`` of ``object_type`` (the object ``name``, or any)."""
    if normalise(target.object) != normalise(object_type) or \
            normalise(target.field) != normalise(field):
        return False
    return name is None or matches_name(target.name, name)
