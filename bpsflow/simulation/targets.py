"""How a parameter's value reaches its targets: shared by both backends.

A parameter targets IDF fields (object type, object name or ``*``, field
name as in the IDD, compared without case, spaces or punctuation), weather
quantities or boundary samplers (see :mod:`bpsflow.config`). Its ``mode``
says how a sampled value combines with the model's nominal value.
"""

from __future__ import annotations

from bpsflow.simulation.idf import normalise

__all__ = ["apply_mode", "normalise", "matches_name"]


def apply_mode(mode: str, nominal: float, value: float) -> float:
    """The field value for a sampled ``value``: replace (absolute), multiply (relative) or add."""
    if mode == "relative":
        return nominal * value
    if mode == "additive":
        return nominal + value
    return value


def matches_name(pattern: str, name: str) -> bool:
    """Whether a target's object name (``*`` for every object) selects ``name`` (no case)."""
    return pattern == "*" or pattern.strip().upper() == name.strip().upper()
