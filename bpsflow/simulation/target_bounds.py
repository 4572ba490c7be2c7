"""Whether the values the parameters give their IDF fields are values EnergyPlus accepts.

Checked the same on every backend, before anything runs:

- :func:`check_target_fields` — every IDF target names an object type and a
  field the EnergyPlus IDD defines (a misspelt field is an error, never a
  field silently left alone);
- :func:`check_distribution_support` (``bpsflow check``, and every command
  that runs instances) — the whole range each parameter's distribution can
  draw, combined with the model's nominal value by its ``mode``, stays within
  the IDD bounds of every field it targets (:mod:`.field_limits`), and a
  glazing pane's transmittance and reflectance cannot sum to 1 or more;
- :func:`check_sample_values` (``bpsflow sample`` and ``run``) — the same for
  the drawn samples, naming the first offending instance.

The range a distribution "can draw" is its inverse CDF at the design's
extreme unit values (:data:`bpsflow.sampling.UNIT_EPS` from 0 and 1), exactly
what a Latin hypercube can reach, so a config ``check`` passes never draws a
refused sample. Several parameters on one field combine in config order, as
:func:`bpsflow.simulation.targets.apply_mode` writes them, by interval
arithmetic.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.simulation.field_limits import (
    SUM_BELOW_ONE,
    Limits,
    UnknownFieldError,
    check_value,
    field_limits,
    field_position,
)
from bpsflow.simulation.idf import IdfObject, model_objects, normalise
from bpsflow.simulation.targets import apply_mode, select_objects

if TYPE_CHECKING:
    from bpsflow.config import Config, Parameter

__all__ = ["TargetedField", "targeted_fields", "check_target_fields",
           "check_distribution_support", "check_sample_values", "check_weather_support",
           "inert_targets"]


@dataclass
class TargetedField:
    """One field of one model object that parameters set, with its IDD limits.

    ``nominal`` is the model's value (``None`` when the field is blank or not
    a number); ``parameters`` are the parameters on it, in config order.
    """

    obj: IdfObject
    position: int
    limits: Limits
    nominal: float | None
    parameters: list[Parameter] = field(default_factory=list)

    @property
    def where(self) -> str:
        return f"{self.obj.where} field '{self.limits.field}'"

    @property
    def names(self) -> str:
        return ", ".join(p.name for p in self.parameters)


def _nominal(obj: IdfObject, position: int) -> float | None:
    text = obj.fields[position].strip() if position < len(obj.fields) else ""
    try:
        return float(text)
    except ValueError:
        return None  # blank (the IDD default), autosize, autocalculate


def targeted_fields(config: Config) -> list[TargetedField]:
    """Every model field the config's parameters set, each once, with its parameters.

    Raises
    ------
    BpsflowError
        Naming the parameter and target when its object type or field is not
        in the EnergyPlus IDD.
    """
    from bpsflow.config import IdfTarget

    objects = model_objects(config.model)
    found: dict[tuple[int, int], TargetedField] = {}
    set_by: dict[tuple[int, int, int], int] = {}   # (parameter, object, field) -> target
    for i, parameter in enumerate(config.parameters):
        for j, target in enumerate(parameter.targets):
            if not isinstance(target, IdfTarget):
                continue
            where = f"parameters[{i}] ({parameter.name}).targets[{j}]"
            try:
                position = field_position(target.object, target.field)
            except UnknownFieldError as exc:
                key = "field" if "has no field" in str(exc) else "object"
                raise BpsflowError(f"{where}.{key}: {exc}", source=config.source) from None
            limits = field_limits(target.object, target.field)
            of_type = [(k, o) for k, o in enumerate(objects.objects)
                       if normalise(o.type) == normalise(target.object)]
            for k, obj in select_objects(of_type, target.name, lambda pair: pair[1].name):
                earlier = set_by.setdefault((i, k, position), j)
                if earlier != j and parameter.mode != "absolute":
                    # each target applies the change: the field would move twice
                    raise BpsflowError(
                        f"{where}: {obj.where} {target.field} is also selected by "
                        f"targets[{earlier}], so the {parameter.mode} change would apply "
                        f"twice; expected each field once per parameter (narrow the "
                        f"name pattern or drop one target)", source=config.source)
                entry = found.setdefault((k, position), TargetedField(
                    obj=obj, position=position, limits=limits, nominal=_nominal(obj, position)))
                if all(p is not parameter for p in entry.parameters):
                    entry.parameters.append(parameter)
    return list(found.values())


def check_target_fields(config: Config) -> list[TargetedField]:
    """Check that every IDF target is a field of the IDD and names objects the model has.

    A target whose object name matches nothing in the model is the config's mistake on
    any backend (a typo, a renamed object), and is reported as such.
    """
    from bpsflow.config import IdfTarget
    from bpsflow.simulation.idf import describe_model, missing_semicolon_hint

    fields = targeted_fields(config)
    objects = model_objects(config.model)
    for i, parameter in enumerate(config.parameters):
        for j, target in enumerate(parameter.targets):
            if not isinstance(target, IdfTarget):
                continue
            of_type = [o for o in objects.objects if normalise(o.type) == normalise(target.object)]
            if not select_objects(of_type, target.name, lambda o: o.name):
                names = sorted({o.name for o in of_type})
                raise BpsflowError(
                    f"parameters[{i}] ({parameter.name}).targets[{j}]: no {target.object} "
                    f"object named '{target.name}' in {describe_model(config.model)} (objects "
                    f"of that type: {names[:12] or 'none'}{' ...' if len(names) > 12 else ''})"
                    f"{missing_semicolon_hint(config.model)}", source=config.source)
    for entry in fields:
        if entry.nominal is None and any(p.mode != "absolute" for p in entry.parameters):
            # an absolute parameter first gives it a number; a change of text cannot apply
            first = entry.parameters[0]
            if first.mode == "absolute":
                continue
            text = entry.obj.fields[entry.position].strip() \
                if entry.position < len(entry.obj.fields) else ""
            label = f"field '{entry.limits.field}'"
            index = config.parameters.index(first)
            article = "an" if first.mode == "additive" else "a"
            raise BpsflowError(
                f"parameters[{index}] ({first.name}): {entry.obj.where} {label} holds "
                f"'{text}', not a number (blank: EnergyPlus's default, autosize, text), so "
                f"{article} {first.mode} change cannot apply; expected a field with a number in "
                f"the model, or mode absolute", source=config.source)
    return fields


def _reach(parameter: Parameter) -> tuple[float, float]:
    """The lowest and highest value the design can draw from a parameter's distribution."""
    from bpsflow.sampling import UNIT_EPS

    ends = parameter.distribution.ppf(np.array([UNIT_EPS, 1.0 - UNIT_EPS], dtype=float))
    return float(np.min(ends)), float(np.max(ends))


def _combine(mode: str, low: float, high: float, a: float, b: float) -> tuple[float, float]:
    if mode == "absolute":
        return a, b
    if mode == "additive":
        return low + a, high + b
    corners = [low * a, low * b, high * a, high * b]
    return min(corners), max(corners)


def _interval(entry: TargetedField) -> tuple[float, float] | None:
    """The range of values the field can take over the design (``None``: no number to check)."""
    low = high = entry.nominal
    for parameter in entry.parameters:
        a, b = _reach(parameter)
        if low is None or high is None:
            if parameter.mode != "absolute":
                return None  # the backends refuse a relative change of a blank field
            low, high = a, b
            continue
        low, high = _combine(parameter.mode, low, high, a, b)
    if low is None or high is None:
        return None
    return low, high


def _how(entry: TargetedField) -> str:
    parts = [f"{p.name} ({p.mode}, {p.distribution.type})" for p in entry.parameters]
    base = f"nominal {entry.nominal:g}" if entry.nominal is not None else "no nominal value"
    return f"{' then '.join(parts)} on the model's {base}"


def check_distribution_support(config: Config) -> None:
    """Refuse a parameter whose distribution can give a field a value EnergyPlus rejects.

    Raises
    ------
    BpsflowError
        Naming the parameter(s), the object and field, the IDD bound and the
        offending end of the range (or the glazing sum that reaches 1).
    """
    entries = targeted_fields(config)
    ranges: dict[tuple[int, int], tuple[float, float]] = {}
    for entry in entries:
        reach = _interval(entry)
        if reach is None:
            continue
        ranges[(id(entry.obj), entry.position)] = reach
        for end in reach:
            problem = check_value(entry.limits, end)
            if problem:
                raise BpsflowError(
                    f"parameters ({entry.names}): the design can set {entry.where} to "
                    f"{end:.6g} ({_how(entry)} ranges over {reach[0]:.6g}..{reach[1]:.6g}), "
                    f"which EnergyPlus refuses: the IDD requires {entry.limits.describe()} "
                    f"({problem}). Narrow the distribution (lower/upper) or change the mode",
                    source=config.source)
    _check_sums(config, entries, lambda entry: ranges.get((id(entry.obj), entry.position)))
    # after the engine's own bounds: a value EnergyPlus refuses is the first thing to fix
    for entry in entries:
        last_absolute = max((k for k, p in enumerate(entry.parameters) if p.mode == "absolute"),
                            default=None)
        if last_absolute:
            overridden = [p.name for p in entry.parameters[:last_absolute]]
            raise BpsflowError(
                f"parameters ({entry.names}): {entry.parameters[last_absolute].name} (absolute) "
                f"sets {entry.where} after {', '.join(overridden)}, whose value it replaces: "
                f"{overridden[0]} would have no effect on the model. Target the field with one "
                "of them, or make the later one relative or additive", source=config.source)


#: Top-of-atmosphere irradiance, W/m² (Kopp & Lean 2011).
SOLAR_CONSTANT_W_M2 = 1361.0


def check_weather_support(config: Config, columns: dict[str, np.ndarray],
                          instance: dict[str, float] | None = None) -> None:
    """Refuse weather perturbations that take a quantity outside the EPW's valid range.

    ``columns`` are the weather file's own values (:attr:`bpsflow.weather.EpwFile.columns`).
    ``instance`` (parameter name -> value), when given, are one instance's values (a truth)
    checked instead of each distribution's reach.
    The same ranges refuse a weather file with such values (:data:`bpsflow.weather.EPW_RANGES`):
    a dry-bulb bias of +80 °C is a unit or typing mistake, and EnergyPlus only warns and
    runs on. Irradiance and wind are clipped at zero where a perturbation takes them below
    (a sensor offset at night), so only their upper bound is checked here; wind
    direction is taken modulo 360.

    Raises
    ------
    BpsflowError
        Naming the parameter(s), the weather quantity, the range the design reaches and
        the valid range.
    """
    from bpsflow.config import WeatherTarget
    from bpsflow.weather import EPW_RANGES

    on_field: dict[str, list[Parameter]] = {}
    for parameter in config.parameters:
        for target in parameter.targets:
            if isinstance(target, WeatherTarget) and parameter not in on_field.get(
                    target.weather, []):
                on_field.setdefault(target.weather, []).append(parameter)
    what = "the truth values" if instance is not None else "the design"
    clipped_at_zero = {"wind_speed", "wind_direction", "global_horizontal_radiation",
                       "diffuse_horizontal_radiation", "direct_normal_radiation"}
    for quantity, parameters in on_field.items():
        if quantity not in EPW_RANGES or quantity not in columns:
            continue
        valid_low, valid_high, _, unit = EPW_RANGES[quantity]
        if quantity.endswith("_radiation"):
            # the EPW dictionary bounds irradiance below only; a gain on a clear-sky peak is
            # physics, twice the solar constant is a unit slip
            valid_high = 2.0 * SOLAR_CONSTANT_W_M2
        values = columns[quantity][np.isfinite(columns[quantity])]
        if values.size == 0:
            continue
        low, high = float(values.min()), float(values.max())
        middle = float(np.median(values[values > 0])) if (values > 0).any() else 0.0
        middle_low = middle_high = middle
        for parameter in parameters:
            a, b = (instance[parameter.name],) * 2 if instance and parameter.name in instance \
                else _reach(parameter)
            low, high = _combine(parameter.mode, low, high, a, b)
            middle_low, middle_high = _combine(parameter.mode, middle_low, middle_high, a, b)
        if quantity in clipped_at_zero and quantity != "wind_direction" and middle > 0 \
                and middle_high <= 0:
            # clipping at zero is for an offset at night or in calm hours; a design that takes
            # the typical hour to zero at every draw has removed the quantity, not perturbed it
            names = ", ".join(p.name for p in parameters)
            raise BpsflowError(
                f"parameters ({names}): even the largest value of {what} takes the "
                f"weather's typical {quantity} ({middle:.6g} {unit}, the median of its non-zero "
                f"hours) to {middle_high:.6g} {unit}, which is clipped to 0: the perturbation "
                f"removes the quantity. Check the distribution's sign, unit and bounds (an "
                f"offset is a few {unit}; a relative change lies above -1)",
                source=config.source)
        below = low < valid_low and quantity not in clipped_at_zero
        # wind direction is taken modulo 360
        if below or (high > valid_high and quantity != "wind_direction"):
            names = ", ".join(p.name for p in parameters)
            how = " then ".join(f"{p.name} ({p.mode}, {p.distribution.type})"
                                for p in parameters)
            raise BpsflowError(
                f"parameters ({names}): {what} can take the weather's {quantity} to "
                f"{low if below else high:.6g} {unit} ({how} on the file's "
                f"{values.min():.6g}..{values.max():.6g} {unit} reaches {low:.6g}..{high:.6g}), "
                f"outside the valid {valid_low:g}..{valid_high:g} {unit} of an EPW file. "
                "Check the distribution's unit and bounds (a sensor error is a few units, "
                "in the quantity's own unit)", source=config.source)


def inert_targets(config: Config) -> list[str]:
    """Fields a parameter cannot move: a relative change of a model value of zero.

    ``0 × factor`` stays 0, so such a parameter does nothing on that object (a design
    flow left at 0 beside objects sized by area). Returned as notes, one per parameter.
    """
    inert: dict[str, list[str]] = {}
    for entry in targeted_fields(config):
        if entry.nominal == 0 and entry.parameters and \
                all(p.mode == "relative" for p in entry.parameters):
            for parameter in entry.parameters:
                inert.setdefault(parameter.name, []).append(entry.where)
    return [f"{name} (relative) cannot move {len(wheres)} field(s) whose model value is 0: "
            f"{'; '.join(wheres[:3])}{' ...' if len(wheres) > 3 else ''}"
            for name, wheres in inert.items()]


def _spectral_average(obj: IdfObject) -> bool:
    """Whether a glazing's optical data are the spectral averages its T and R fields give."""
    kind = obj.fields[1].strip().upper() if len(obj.fields) > 1 else ""
    return kind in ("", "SPECTRALAVERAGE")


def _check_sums(config: Config, entries: list[TargetedField], reach) -> None:
    """Glazing T + R (or T + emissivity) must stay below 1 over each field's range."""
    by_object: dict[int, list[TargetedField]] = {}
    for entry in entries:
        by_object.setdefault(id(entry.obj), []).append(entry)
    for targeted in by_object.values():
        obj = targeted[0].obj
        pairs = SUM_BELOW_ONE.get(obj.type, ())
        if not pairs or not _spectral_average(obj):
            continue
        for first, second in pairs:
            highs: list[float | None] = []
            names: list[str] = []
            for name in (first, second):
                on_field = next((e for e in targeted
                                 if normalise(e.limits.field) == normalise(name)), None)
                if on_field is not None and reach(on_field) is not None:
                    highs.append(reach(on_field)[1])
                    names.append(on_field.names)
                else:
                    highs.append(_nominal(obj, field_position(obj.type, name)))
            a, b = highs
            if names and a is not None and b is not None and not a + b < 1.0:
                raise BpsflowError(
                    f"parameters ({', '.join(names)}): the design can set {obj.where} "
                    f"'{first}' + '{second}' to {a:.6g} + {b:.6g} = "
                    f"{a + b:.6g}, which EnergyPlus refuses (a pane cannot "
                    f"transmit and reflect more than what falls on it: the sum must be < 1). "
                    f"Narrow the distributions", source=config.source)


def field_samples(config: Config, entry: TargetedField, samples: pd.DataFrame
                  ) -> np.ndarray | None:
    """The field's value per sample (rows of ``samples``), as the backends write it."""
    values: np.ndarray | None = None if entry.nominal is None else \
        np.full(len(samples), entry.nominal)
    for parameter in entry.parameters:
        if parameter.name in samples.columns:
            column = samples[parameter.name].to_numpy(dtype=float)
        else:  # the backends hold a parameter missing from the samples at its nominal value
            column = np.full(len(samples), float(parameter.distribution.nominal))
        if values is None:
            if parameter.mode != "absolute":
                return None
            values = column
        else:
            values = np.asarray(apply_mode(parameter.mode, values, column), dtype=float)  # type: ignore[arg-type]
    return values


def check_sample_values(config: Config, samples: pd.DataFrame, where: str = "samples",
                        entries: list[TargetedField] | None = None) -> None:
    """Refuse drawn samples that give a field a value EnergyPlus rejects, naming the first.

    Parameters
    ----------
    config : Config
    samples : DataFrame
        Indexed by instance, one column per parameter.
    where : str
        What the samples are, for the message (``samples.parquet``).
    entries : list of TargetedField, optional
        ``targeted_fields(config)``, when the caller checks many samples of one config.

    Raises
    ------
    BpsflowError
        Naming the instance, the parameter(s), the value, the field and the bound.
    """
    if "instance" in samples.columns:
        samples = samples.set_index("instance")
    entries = targeted_fields(config) if entries is None else entries
    per_field: dict[tuple[int, int], np.ndarray] = {}
    for entry in entries:
        values = field_samples(config, entry, samples)
        if values is None:
            continue
        per_field[(id(entry.obj), entry.position)] = values
        low, high = entry.limits.minimum, entry.limits.maximum
        bad = ~np.isfinite(values)
        if low is not None:
            bad |= values <= low if entry.limits.minimum_exclusive else values < low
        if high is not None:
            bad |= values >= high if entry.limits.maximum_exclusive else values > high
        if bad.any():
            row = int(np.argmax(bad))
            value = float(values[row])
            drawn = ", ".join(f"{p.name} = {float(samples[p.name].iloc[row]):.6g}"
                              for p in entry.parameters if p.name in samples.columns)
            raise BpsflowError(
                f"{where}: instance {samples.index[row]} ({drawn}; {int(bad.sum())} of "
                f"{len(values)} instances alike) sets {entry.where} to {value:.6g}, which "
                f"EnergyPlus refuses: the IDD requires {entry.limits.describe()} "
                f"({check_value(entry.limits, value)})", source=config.source)
    by_object: dict[int, list[TargetedField]] = {}
    for entry in entries:
        by_object.setdefault(id(entry.obj), []).append(entry)
    for targeted in by_object.values():
        obj = targeted[0].obj
        if obj.type not in SUM_BELOW_ONE or not _spectral_average(obj):
            continue
        for first, second in SUM_BELOW_ONE[obj.type]:
            columns, names = [], []
            for name in (first, second):
                position = field_position(obj.type, name)
                if (id(obj), position) in per_field:
                    columns.append(per_field[(id(obj), position)])
                    names += [p.name for e in targeted if e.position == position
                              for p in e.parameters]
                else:
                    nominal = _nominal(obj, position)
                    columns.append(np.full(len(samples), np.nan if nominal is None else nominal))
            if not names:
                continue
            total = columns[0] + columns[1]
            bad = total >= 1.0
            if bad.any():
                row = int(np.argmax(bad))
                drawn = ", ".join(f"{name} = {float(samples[name].iloc[row]):.6g}"
                                  for name in dict.fromkeys(names) if name in samples.columns)
                raise BpsflowError(
                    f"{where}: instance {samples.index[row]} ({drawn}) sets {obj.where} "
                    f"'{first}' + '{second}' to {columns[0][row]:.6g} + {columns[1][row]:.6g} = "
                    f"{total[row]:.6g}, which EnergyPlus refuses (the sum must be < 1; "
                    f"{int(bad.sum())} of {len(total)} instances alike)", source=config.source)
