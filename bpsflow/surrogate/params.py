"""Sampled values of IDF fields for an ensemble, read the way the EnergyPlus backend writes them.

:class:`FieldValues` holds, for every (object type, object name, field) a
config parameter targets, the per-instance value (``apply_mode`` on the
model's nominal value, exactly as the EnergyPlus backend writes the field).
The physics asks it for the fields it needs with :meth:`FieldValues.get`;
untargeted fields give the model's nominal value. Which targeted fields were
never asked for is what the surrogate has no physics for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from bpsflow.config import BoundaryTarget, Config, IdfTarget, WeatherTarget
from bpsflow.errors import BpsflowError
from bpsflow.simulation.field_limits import UnknownFieldError, field_position
from bpsflow.simulation.idf import FIELDS, UNNAMED, IdfModel, describe_model, normalise
from bpsflow.simulation.targets import apply_mode, select_objects

Key = tuple[str, str, str]  # (TYPE, NAME upper, normalised field)


@dataclass
class FieldValues:
    idf: IdfModel
    n: int
    values: dict[Key, np.ndarray] = field(default_factory=dict)
    #: targeted key -> human-readable label and the parameters that target it
    targeted: dict[Key, tuple[str, list[str]]] = field(default_factory=dict)
    #: targets on object types/fields outside the surrogate's table
    unknown: dict[str, list[str]] = field(default_factory=dict)
    used: set[Key] = field(default_factory=set)

    def get(self, object_type: str, name: str, field_name: str,
            default: float | None = None) -> np.ndarray:
        """Per-instance value ``(n,)`` of a field (sampled if targeted, else nominal)."""
        key = (object_type.upper(), name.upper(), normalise(field_name))
        self.used.add(key)
        if key in self.values:
            return self.values[key]
        obj = self.idf.find(object_type, name) if name else self.idf.one(object_type)
        return np.full(self.n, obj.number(field_name, default))

    def ignored(self) -> list[str]:
        """Targets with no physics in the surrogate: ``'Type Name: Field (parameter)'``."""
        out = [f"{label} ({', '.join(params)})" for key, (label, params) in self.targeted.items()
               if key not in self.used]
        out += [f"{label} ({', '.join(params)})" for label, params in self.unknown.items()]
        return out


def sample_columns(config: Config, samples: pd.DataFrame) -> pd.DataFrame:
    """Samples indexed by instance with one float column per parameter (nominal if missing)."""
    frame = samples
    if "instance" in frame.columns:
        frame = frame.set_index("instance")
    out = {}
    for parameter in config.parameters:
        if parameter.name in frame.columns:
            out[parameter.name] = frame[parameter.name].to_numpy(dtype=float)
        else:
            out[parameter.name] = np.full(len(frame), float(parameter.distribution.nominal))
    return pd.DataFrame(out, index=frame.index)


def field_values(config: Config, idf: IdfModel, samples: pd.DataFrame) -> FieldValues:
    """Apply every parameter's IDF targets to the nominal model, per instance.

    Raises
    ------
    BpsflowError
        When a target names an object that is not in the model, or a field
        the object type does not have, like the EnergyPlus backend does.
    """
    values = FieldValues(idf=idf, n=len(samples))
    for i, parameter in enumerate(config.parameters):
        column = samples[parameter.name].to_numpy(dtype=float)
        for j, target in enumerate(parameter.targets):
            if isinstance(target, (WeatherTarget, BoundaryTarget)):
                continue
            _apply_target(values, config, parameter, target, column,
                          f"parameters[{i}] ({parameter.name}).targets[{j}]")
    return values


def _apply_target(values: FieldValues, config: Config, parameter, target: IdfTarget,
                  column: np.ndarray, where: str) -> None:
    object_type = target.object.upper()
    objects = values.idf.of_type(object_type)
    if not objects:
        raise BpsflowError(f"{where}: no {target.object} object in {describe_model(config.model)}",
                           source=config.source)
    chosen = select_objects(objects, target.name)
    if target.name != "*":
        if not chosen:
            names = sorted({o.name for o in objects})
            raise BpsflowError(f"{where}: no {target.object} object named '{target.name}' in "
                               f"{describe_model(config.model)} (objects of that type: "
                               f"{names})",
                               source=config.source)
    try:  # a field EnergyPlus does not have is a mistake, not a field without physics
        field_position(target.object, target.field)
    except UnknownFieldError as exc:
        which = "field" if "has no field" in str(exc) else "object"
        raise BpsflowError(f"{where}.{which}: {exc}", source=config.source) from None
    label = f"{target.object} {target.name}: {target.field}"
    if object_type not in FIELDS or chosen[0].field_index(target.field) is None:
        values.unknown.setdefault(label, []).append(parameter.name)
        return
    for obj in chosen:
        name = "" if object_type in UNNAMED else obj.name.upper()
        key = (object_type, name, normalise(target.field))
        nominal = obj.number(target.field, 0.0) if parameter.mode != "absolute" else 0.0
        values.values[key] = np.asarray(apply_mode(parameter.mode, nominal, column), dtype=float)
        shown = f"{target.object} {obj.name or '*'}: {target.field}"
        entry = values.targeted.setdefault(key, (shown, []))
        if parameter.name not in entry[1]:
            entry[1].append(parameter.name)
