"""The true values a simpler model should recover when the "real" building is a detailed one.

A prototype-room model (seed §4.2.2) stands one zone, with a multiplier, for
many rooms; the detailed "real" floor behind synthetic data (the seed's
baseline, §4.2.3) gives each room its own usage and setpoint. A parameter such
as "lighting power of the cellular offices" then has no single true value: the
true value is the one the prototype zone must carry to stand for the rooms,
which is what a calibration of the prototype model can at best recover. Truth
coverage judged against the truth file's nominal value would count a correct
posterior as a miss whenever the rooms' own variation moves the mean.

The equivalent value of a parameter comes from the fields it sets in both
models (the same config targets, read by :mod:`bpsflow.simulation.target_bounds`):

* the detailed model's field values under the truth, each field through the
  parameter's mode (``apply_mode``), averaged over every field the parameter
  sets there (one per room);
* the value ``θ`` that gives the simpler model's fields the same average:
  ``relative`` ``θ = mean(truth · v_r) / mean(v_m)``; ``additive``
  ``θ = mean(truth + v_r) − mean(v_m)``; ``absolute`` ``θ = mean(truth)``,
  the truth itself.

Each field counts once per room it stands for: the multiplier of its zone
(an object naming a zone, or reached from one through name references: a
window through its wall, a setpoint schedule through its thermostat; the sum
when it serves several zones), 1 for an object of no zone, 0 for a schedule
nothing uses. Means are weighted by those counts, so the prototype's one
office with multiplier 16 meets the detailed floor's 16 offices. A parameter
without IDF targets, or whose targets hold no number in either model, keeps
its truth value; the record says which.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bpsflow.config import Config, IdfTarget, Parameter
from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import IdfObject, model_objects
from bpsflow.simulation.target_bounds import TargetedField, targeted_fields
from bpsflow.simulation.targets import apply_mode

__all__ = ["Equivalence", "equivalent_values"]


@dataclass
class Equivalence:
    """Equivalent true values for a simpler model, with how each was found.

    Attributes
    ----------
    values : dict
        Parameter name to its equivalent value (the truth's when unchanged).
    how : dict
        Parameter name to a one-line account (fields averaged, or why the
        truth was kept).
    """

    values: dict[str, float]
    how: dict[str, str] = field(default_factory=dict)


#: How many name references away a zone is still looked for (a setpoint schedule's zone is
#: two away: schedule <- thermostat setpoint <- zone thermostat).
_REFERENCE_DEPTH = 3


class _Rooms:
    """How many rooms each object of a model stands for (see the module docstring)."""

    def __init__(self, objects: list[IdfObject]) -> None:
        self.multiplier = {z.name.upper(): _zone_multiplier(z) for z in objects
                           if z.type == "ZONE"}
        self.by_name: dict[str, list[IdfObject]] = {}
        self.users: dict[str, list[IdfObject]] = {}
        for obj in objects:
            if obj.name:
                self.by_name.setdefault(obj.name.upper(), []).append(obj)
        for obj in objects:
            for value in _named(obj):
                if value in self.by_name:
                    self.users.setdefault(value, []).append(obj)

    def _zones_named(self, obj: IdfObject) -> set[str]:
        return {f.strip().upper() for f in obj.fields if f.strip().upper() in self.multiplier}

    def weight(self, obj: IdfObject) -> float:
        if obj.type == "ZONE":
            return self.multiplier[obj.name.upper()]
        for depth in range(_REFERENCE_DEPTH + 1):
            zones = self._zones_within(obj, depth)
            if zones:
                return float(sum(self.multiplier[z] for z in zones))
        unused = obj.type.startswith("SCHEDULE") and not self.users.get(obj.name.upper())
        return 0.0 if unused else 1.0

    def _zones_within(self, obj: IdfObject, depth: int) -> set[str]:
        """Zones ``depth`` references away: up through users, or down through named objects."""
        if depth == 0:
            return self._zones_named(obj)
        zones: set[str] = set()
        for user in self.users.get(obj.name.upper(), []):
            zones |= self._zones_within(user, depth - 1)
        if depth == 1:
            for value in _named(obj):
                for named in self.by_name.get(value, []):
                    zones |= self._zones_named(named)
        return zones


def _named(obj: IdfObject) -> set[str]:
    """The object's field values after its name, as names (upper case) it may refer to."""
    return {f.strip().upper() for f in obj.fields[1:] if f.strip()}


def _zone_multiplier(zone: IdfObject) -> float:
    # Zone fields: Name, Direction of Relative North, X, Y, Z, Type, Multiplier
    text = zone.fields[6].strip() if len(zone.fields) > 6 else ""
    try:
        return float(text) if text else 1.0
    except ValueError:
        return 1.0


def _within_support(parameter: Parameter, value: float) -> bool:
    try:
        low, high = parameter.distribution.scipy().support()
    except (AttributeError, NotImplementedError, TypeError):
        return True  # no density (sampler, constant): nothing to compare with
    return bool(low <= value <= high)


def _fields_of(entries: list[TargetedField], name: str, rooms: _Rooms
               ) -> tuple[np.ndarray, np.ndarray]:
    """Nominal values of the fields parameter ``name`` sets, and the rooms each stands for."""
    mine = [e for e in entries if e.nominal is not None and any(p.name == name
                                                                 for p in e.parameters)]
    return (np.array([e.nominal for e in mine], dtype=float),
            np.array([rooms.weight(e.obj) for e in mine], dtype=float))


def equivalent_values(truth_config: Config, truth_values: dict[str, float],
                      model_config: Config) -> Equivalence:
    """Equivalent values of ``truth_values`` (for ``truth_config``'s model) in ``model_config``'s.

    Parameters
    ----------
    truth_config : Config
        The config of the detailed model that produced the data.
    truth_values : dict
        The true parameter values (``truth.json``'s ``values``), in the
        parameters' own units and modes.
    model_config : Config
        The config of the model to calibrate; its parameters are matched by
        name.

    Returns
    -------
    Equivalence

    Raises
    ------
    BpsflowError
        When a parameter's mode differs between the two configs.
    """
    truth_fields = targeted_fields(truth_config)
    model_fields = targeted_fields(model_config)
    truth_rooms = _Rooms(model_objects(truth_config.model).objects)
    model_rooms = _Rooms(model_objects(model_config.model).objects)
    truth_parameters = {p.name: p for p in truth_config.parameters}
    out = Equivalence(values={})
    for parameter in model_config.parameters:
        name = parameter.name
        if name not in truth_values:
            continue
        value = float(truth_values[name])
        out.values[name] = value
        other = truth_parameters.get(name)
        if other is None or not any(isinstance(t, IdfTarget) for t in parameter.targets):
            out.how[name] = "truth kept: no model fields to compare"
            continue
        if other.mode != parameter.mode:
            raise BpsflowError(f"parameters ({name}).mode: '{parameter.mode}' here but "
                               f"'{other.mode}' in the truth's config {truth_config.source}; "
                               f"an equivalent value needs the same mode",
                               source=model_config.source)
        real, real_rooms = _fields_of(truth_fields, name, truth_rooms)
        mine, my_rooms = _fields_of(model_fields, name, model_rooms)
        if real_rooms.sum() <= 0 or my_rooms.sum() <= 0:
            out.how[name] = "truth kept: its fields hold no number (or serve no room) in one " \
                            "of the models"
            continue
        realised = float(np.average([apply_mode(parameter.mode, v, value) for v in real],
                                    weights=real_rooms))
        base = float(np.average(mine, weights=my_rooms))
        if parameter.mode == "relative":
            if base == 0:
                out.how[name] = "truth kept: the model's fields are 0"
                continue
            equivalent = realised / base
        elif parameter.mode == "additive":
            equivalent = realised - base
        else:
            equivalent = realised
        if not _within_support(other, equivalent):
            out.how[name] = (f"truth kept: the equivalent {equivalent:.4g} is outside the "
                             f"prior's support, so the two models' fields differ in kind "
                             f"(e.g. one object sized for a multiplied zone)")
            continue
        out.values[name] = equivalent
        out.how[name] = (f"{len(real)} field(s) for {real_rooms.sum():g} room(s) in the "
                         f"truth's model, {len(mine)} for {my_rooms.sum():g} here "
                         f"({parameter.mode}, room-weighted means)")
    return out
