"""What the EnergyPlus IDD allows in an IDF field: its name and its numeric bounds.

Every backend refuses, before anything runs, a parameter target on a field
the object type does not have and a value EnergyPlus would reject: outside
the IDD's ``\\minimum``/``\\minimum>``/``\\maximum``/``\\maximum<``, or, for a
``WindowMaterial:Glazing`` pane, a transmittance and reflectance (or
emissivity) that sum to 1 or more (EnergyPlus checks these sums itself; the
IDD cannot express them).

The surrogate runs without EnergyPlus installed, so the limits come from a
compact extract of the EnergyPlus 25.2 IDD bundled with the package
(``idd_fields.json.gz``: every object type, its field names in order and the
numeric bounds). ``python -m bpsflow.simulation.field_limits Energy+.idd``
writes it again from an IDD; a test compares it with the installed one.

Field and type names are compared without case, spaces or punctuation, as
everywhere in the project (:func:`normalise`, which :mod:`.idf` uses too).
"""

from __future__ import annotations

import gzip
import json
import math
import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from bpsflow.errors import BpsflowError
from bpsflow.files import write_bytes_atomic

__all__ = ["Limits", "UnknownFieldError", "field_limits", "field_position", "object_fields",
           "check_value", "clip_to_limits", "known_object_types", "SUM_BELOW_ONE", "check_sums", "parse_idd"]

#: The bundled extract of the IDD (see the module docstring).
EXTRACT = Path(__file__).with_name("idd_fields.json.gz")

#: Field pairs of an object type whose values EnergyPlus requires to sum to less than 1
#: (a pane cannot transmit and reflect, or transmit and emit, more than what falls on it).
#: They apply when the pane's optical data are spectral averages (the default).
SUM_BELOW_ONE: dict[str, tuple[tuple[str, str], ...]] = {
    "WINDOWMATERIAL:GLAZING": (
        ("Solar Transmittance at Normal Incidence",
         "Front Side Solar Reflectance at Normal Incidence"),
        ("Solar Transmittance at Normal Incidence",
         "Back Side Solar Reflectance at Normal Incidence"),
        ("Visible Transmittance at Normal Incidence",
         "Front Side Visible Reflectance at Normal Incidence"),
        ("Visible Transmittance at Normal Incidence",
         "Back Side Visible Reflectance at Normal Incidence"),
        ("Infrared Transmittance at Normal Incidence",
         "Front Side Infrared Hemispherical Emissivity"),
        ("Infrared Transmittance at Normal Incidence",
         "Back Side Infrared Hemispherical Emissivity"),
    ),
}


@lru_cache(maxsize=4096)
def normalise(name: str) -> str:
    """Field/type names compared without case, spaces or punctuation (memoised: every run
    of a batch matches its targets against the model's objects)."""
    return re.sub(r"[^a-z0-9]", "", name.lower())


class UnknownFieldError(BpsflowError):
    """An object type the IDD does not define, or a field its type does not have."""


@dataclass(frozen=True)
class Limits:
    """One IDD field: its name as the IDD spells it, whether it is numeric, and its bounds.

    ``minimum``/``maximum`` are ``None`` where the IDD sets none; an exclusive
    bound (``\\minimum>``, ``\\maximum<``) excludes the bound itself.
    """

    object_type: str
    field: str
    numeric: bool = False
    minimum: float | None = None
    minimum_exclusive: bool = False
    maximum: float | None = None
    maximum_exclusive: bool = False

    @property
    def bounded(self) -> bool:
        return self.minimum is not None or self.maximum is not None

    def describe(self) -> str:
        """The bounds as text: ``> 0``, ``≥ 0 and ≤ 1``, or ``any number``."""
        parts = []
        if self.minimum is not None:
            parts.append(f"{'>' if self.minimum_exclusive else '≥'} {self.minimum:g}")
        if self.maximum is not None:
            parts.append(f"{'<' if self.maximum_exclusive else '≤'} {self.maximum:g}")
        return " and ".join(parts) or "any number"


def parse_idd(text: str) -> dict[str, tuple[str, list[Limits]]]:
    """Object types of an IDD's text: upper-case type -> (spelling, its fields in order).

    Reads ``A1 , \\field Name`` lines and the ``\\minimum``, ``\\minimum>``,
    ``\\maximum`` and ``\\maximum<`` notes under them; everything else is skipped.
    """
    types: dict[str, tuple[str, list[Limits]]] = {}
    fields: list[Limits] | None = None
    spelling = ""
    current: dict | None = None

    def close() -> None:
        if fields is not None and current is not None:
            fields.append(Limits(object_type=spelling, **current))

    object_line = re.compile(r"^([A-Za-z][^,;!\\]*)[,;]")
    field_line = re.compile(r"^\s+([AN])\d+\s*[,;]\s*\\field\s+(.*?)\s*$")
    bound_line = re.compile(r"^\s*\\(minimum|maximum)\s*([<>]?)\s*(\S+)")
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("!"):
            continue
        match = object_line.match(line)
        if match and not line.startswith((" ", "\t", "\\")):
            close()
            current = None
            spelling = match[1].strip()
            fields = []
            types[spelling.upper()] = (spelling, fields)
            continue
        match = field_line.match(line)
        if match and fields is not None:
            close()
            current = {"field": match[2], "numeric": match[1] == "N"}
            continue
        match = bound_line.match(line)
        if match and current is not None:
            try:
                value = float(match[3])
            except ValueError:
                continue  # e.g. "\minimum> 0.0 autosize": not a number bound
            current[match[1]] = value
            current[f"{match[1]}_exclusive"] = bool(match[2])
    close()
    return types


def write_extract(idd: Path, path: Path = EXTRACT) -> Path:
    """Write the compact extract of ``idd`` that the package ships (see the module docstring)."""
    types = parse_idd(Path(idd).read_text(errors="replace"))
    data = {key: [spelling, [_pack(f) for f in fields]] for key, (spelling, fields) in types.items()}
    return write_bytes_atomic(path, gzip.compress(json.dumps(data, separators=(",", ":")).encode(),
                                                mtime=0))


def _pack(limits: Limits) -> list:
    packed: list = [limits.field, int(limits.numeric)]
    if limits.bounded:
        packed += [limits.minimum, int(limits.minimum_exclusive), limits.maximum,
                   int(limits.maximum_exclusive)]
    return packed


@lru_cache(maxsize=1)
def _extract() -> dict[str, tuple[str, tuple[Limits, ...]]]:
    data = json.loads(gzip.decompress(EXTRACT.read_bytes()))
    types = {}
    for key, (spelling, fields) in data.items():
        unpacked = []
        for packed in fields:
            name, numeric, *bounds = packed
            lower, lower_x, upper, upper_x = bounds or (None, 0, None, 0)
            unpacked.append(Limits(spelling, name, bool(numeric), lower, bool(lower_x), upper,
                                   bool(upper_x)))
        types[normalise(key)] = (spelling, tuple(unpacked))
    return types


def known_object_types() -> dict[str, str]:
    """Every object type of the IDD: upper case -> the IDD's spelling."""
    return {spelling.upper(): spelling for spelling, _ in _extract().values()}


def object_fields(object_type: str) -> tuple[Limits, ...]:
    """Every field of ``object_type`` after the type itself, in IDD order.

    Raises
    ------
    UnknownFieldError
        When the IDD defines no such object type.
    """
    found = _extract().get(normalise(object_type))
    if found is None:
        raise UnknownFieldError(f"'{object_type}' is not an EnergyPlus 25.2 object type (IDD)")
    return found[1]


def field_position(object_type: str, field_name: str) -> int:
    """The index of ``field_name`` among the fields of ``object_type`` (0 = the first after the type).

    Raises
    ------
    UnknownFieldError
        When the type is unknown or has no such field (naming its fields).
    """
    fields = object_fields(object_type)
    wanted = normalise(field_name)
    for i, limits in enumerate(fields):
        if normalise(limits.field) == wanted:
            return i
    shown = ", ".join(f.field for f in fields[:40]) + (", ..." if len(fields) > 40 else "")
    raise UnknownFieldError(f"{fields[0].object_type if fields else object_type} has no field "
                            f"'{field_name}' in the EnergyPlus 25.2 IDD (its fields: {shown})")


def field_limits(object_type: str, field_name: str) -> Limits:
    """The IDD's name and bounds of one field.

    Raises
    ------
    UnknownFieldError
        When the type is unknown or has no such field.
    """
    return object_fields(object_type)[field_position(object_type, field_name)]


def check_value(limits: Limits, value: float) -> str | None:
    """Why ``value`` breaks ``limits`` (``'-0.5 is not > 0'``), or ``None`` when it is allowed."""
    if not math.isfinite(value):
        return f"{value} is not a finite number"
    low, high = limits.minimum, limits.maximum
    if low is not None and (value < low or (limits.minimum_exclusive and value == low)):
        return f"{value:.6g} is not {'>' if limits.minimum_exclusive else '≥'} {low:g}"
    if high is not None and (value > high or (limits.maximum_exclusive and value == high)):
        return f"{value:.6g} is not {'<' if limits.maximum_exclusive else '≤'} {high:g}"
    return None


def clip_to_limits(limits: Limits, values: np.ndarray | float, *,
                   margin: float = 1e-9) -> np.ndarray:
    """``values`` moved inside ``limits``; an exclusive bound is kept off by ``margin``.

    ``margin`` is relative to the bound (absolute when the bound is 0).
    """
    clipped = np.asarray(values, dtype=float).copy()
    if limits.minimum is not None:
        low = limits.minimum
        if limits.minimum_exclusive:
            low += margin * (abs(low) or 1.0)
        clipped = np.maximum(clipped, low)
    if limits.maximum is not None:
        high = limits.maximum
        if limits.maximum_exclusive:
            high -= margin * (abs(high) or 1.0)
        clipped = np.minimum(clipped, high)
    return clipped


def check_sums(object_type: str, values: Mapping[str, float]) -> str | None:
    """Why an object's field values break a sum EnergyPlus requires below 1, or ``None``.

    ``values`` maps field names (any spelling) to the object's values; a pair
    with a field missing from it is not checked.
    """
    pairs = SUM_BELOW_ONE.get(normalise_type(object_type), ())
    by_name = {normalise(name): value for name, value in values.items()}
    for first, second in pairs:
        a, b = by_name.get(normalise(first)), by_name.get(normalise(second))
        if a is not None and b is not None and not a + b < 1.0:
            return (f"{first} + {second} = {a:.6g} + {b:.6g} = {a + b:.6g}, "
                    f"not < 1 (EnergyPlus refuses the pane)")
    return None


def normalise_type(object_type: str) -> str:
    """The upper-case spelling under which :data:`SUM_BELOW_ONE` lists an object type."""
    wanted = normalise(object_type)
    return next((key for key in SUM_BELOW_ONE if normalise(key) == wanted), object_type.upper())


if __name__ == "__main__":  # pragma: no cover - regenerating the bundled extract
    print(write_extract(Path(sys.argv[1])))
