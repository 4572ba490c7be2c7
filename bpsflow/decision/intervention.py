"""The intervention file of ``bpsflow decide``: the change, the test week, outcomes and rules.

Example (seed §4.4.2; ``configs/`` ships one)::

    name: supply_minus_5K
    change:
      edits:                       # IDF fields changed from the model's own value
      - target: {object: 'SetpointManager:OutdoorAirReset', name: '*',
                 field: Setpoint at Outdoor High Temperature}
        add: -5
        minimum: 25
      overlay: {}                  # optional: config keys merged over the config
    week: {start: 03-20, days: 7}
    outcomes:
    - {name: week_heating_kwh, output: heating_kwh, statistic: total}
    - name: discomfort_degree_hours
      output: zone_air_temperature_c
      statistic: discomfort
      setpoint: {parameter: zone_setpoint}
      hours: {days: weekdays, start_hour: 6, end_hour: 19}
    rules:
    - name: D1
      threshold: 0.5
      underperforms_when: any
      events:
      - {outcome: week_heating_kwh, above: {factor: 1.0}}
      - {outcome: discomfort_degree_hours, above: {factor: 1.0, offset: 0.0}}

Every name is checked against the config before anything runs: outputs,
parameters, outcomes of the rules, and the overlay through the config schema.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import yaml
from pydantic import BaseModel, Field, ValidationError, model_validator

from bpsflow.config import Config, IdfTarget, SafeName
from bpsflow.errors import BpsflowError
from bpsflow.schema import StrictModel
from bpsflow.units import normalise_unit


class _Strict(StrictModel):
    pass


def _exactly_one(model: BaseModel, names: tuple[str, ...], message: str) -> None:
    if sum(getattr(model, name) is not None for name in names) != 1:
        raise ValueError(message)


class Edit(_Strict):
    """A change to IDF fields: ``set`` a value, or ``add`` to / ``multiply`` the model's value.

    ``minimum``/``maximum`` bound the result (the source: the supply temperature
    lowered by 5 °C, never below 25 °C).
    """

    target: IdfTarget
    set: float | None = None
    add: float | None = None
    multiply: float | None = None
    minimum: float | None = None
    maximum: float | None = None

    @model_validator(mode="after")
    def _one_change(self) -> Edit:
        _exactly_one(self, ("set", "add", "multiply"), "give exactly one of set, add or multiply")
        if self.minimum is not None and self.maximum is not None and self.minimum > self.maximum:
            raise ValueError(f"minimum ({self.minimum:g}) is above maximum ({self.maximum:g})")
        return self


class Change(_Strict):
    edits: list[Edit] = Field(default_factory=list)
    overlay: dict = Field(default_factory=dict)

    @model_validator(mode="after")
    def _something(self) -> Change:
        if not self.edits and not self.overlay:
            raise ValueError("the change is empty: give edits or an overlay")
        return self


class Week(_Strict):
    """The test period: ``days`` days from ``start`` (MM-DD, in the config's year)."""

    start: str
    days: int = Field(default=7, ge=1, le=366)


class Hours(_Strict):
    """The hours an outcome counts: a day set and an hour range [start_hour, end_hour)."""

    days: Literal["all", "weekdays", "weekends"] = "all"
    start_hour: int = Field(default=0, ge=0, le=23)
    end_hour: int = Field(default=24, ge=1, le=24)

    @model_validator(mode="after")
    def _range(self) -> Hours:
        if self.start_hour >= self.end_hour:
            raise ValueError(f"start_hour ({self.start_hour}) must be before end_hour "
                             f"({self.end_hour}): the range is [start_hour, end_hour) within "
                             "one day (for hours across midnight use two outcomes)")
        return self


class Setpoint(_Strict):
    """The comfort setpoint: a fixed ``value_c``, or the value a calibrated ``parameter`` gives its field."""

    value_c: float | None = None
    parameter: str | None = None

    @model_validator(mode="after")
    def _one(self) -> Setpoint:
        _exactly_one(self, ("value_c", "parameter"), "give either value_c or parameter")
        return self


class Outcome(_Strict):
    """An outcome of the test week from one output's hourly series.

    ``total``: the sum over the week's hours (energies); ``mean``: the mean;
    ``discomfort``: degree-hours under ``setpoint`` per counted hour,
    mean of max(0, setpoint - value) over ``hours`` (°C·h per h).
    """

    name: SafeName
    output: str
    statistic: Literal["total", "mean", "discomfort"]
    hours: Hours = Field(default_factory=Hours)
    setpoint: Setpoint | None = None

    @model_validator(mode="after")
    def _setpoint(self) -> Outcome:
        if self.statistic == "discomfort" and self.setpoint is None:
            raise ValueError("a discomfort outcome needs a setpoint")
        return self


class Bound(_Strict):
    """``factor * business-as-usual + offset``."""

    factor: float = 1.0
    offset: float = 0.0


class Event(_Strict):
    """The intervention's outcome ``above`` (or ``below``) a bound on the business-as-usual one."""

    outcome: str
    above: Bound | None = None
    below: Bound | None = None

    @model_validator(mode="after")
    def _one(self) -> Event:
        _exactly_one(self, ("above", "below"), "give either above or below")
        return self


class Rule(_Strict):
    """Implement unless P(underperformance) exceeds ``threshold``."""

    name: SafeName
    threshold: float = Field(default=0.5, gt=0, lt=1)
    underperforms_when: Literal["any", "all"] = "any"
    events: list[Event] = Field(min_length=1)


class Sampling(_Strict):
    posterior_draws: int = Field(default=100, ge=1, le=10_000)
    permutations: int = Field(default=100, ge=1, le=10_000)
    seed: int = Field(default=0, ge=0, le=2**32 - 1)


class Intervention(_Strict):
    name: SafeName
    change: Change
    week: Week
    outcomes: list[Outcome] = Field(min_length=1)
    rules: list[Rule] = Field(min_length=1)
    sampling: Sampling = Field(default_factory=Sampling)

    @model_validator(mode="after")
    def _names(self) -> Intervention:
        names = [o.name for o in self.outcomes]
        rules = [r.name for r in self.rules]
        for key, listed in (("outcomes", names), ("rules", rules)):
            repeated = sorted({n for n in listed if listed.count(n) > 1})
            if repeated:
                raise ValueError(f"{key}: names must be unique ({', '.join(repeated)} repeated)")
        for i, rule in enumerate(self.rules):
            for j, event in enumerate(rule.events):
                if event.outcome not in names:
                    raise ValueError(f"rules[{i}] ({rule.name}).events[{j}].outcome: unknown "
                                     f"outcome '{event.outcome}', expected one of {names}")
        return self


def load_intervention(path: Path, config: Config) -> Intervention:
    """Read and check an intervention file against ``config``.

    Raises
    ------
    BpsflowError
        Naming the file and key of the first problem: a schema error, an
        output or parameter the config does not have, a week outside the
        config's tests.
    """
    from bpsflow.config import _first_problem, parse_yaml, test_dates
    from bpsflow.files import read_user_text

    path = Path(path)
    try:
        raw = parse_yaml(read_user_text(path, "an intervention file (YAML)"))
    except yaml.YAMLError as exc:
        raise BpsflowError(f"not valid YAML: {exc}", source=path) from None
    if not isinstance(raw, dict):
        raise BpsflowError("expected a mapping with name, change, week, outcomes and rules",
                           source=path)
    try:
        intervention = Intervention.model_validate(raw)
    except ValidationError as exc:
        _, where, message = _first_problem(exc, raw)
        raise BpsflowError(f"{where}: {message}", source=path) from None
    for i, outcome in enumerate(intervention.outcomes):
        if outcome.output not in config.outputs:
            raise BpsflowError(f"outcomes[{i}] ({outcome.name}).output: unknown output "
                               f"'{outcome.output}', expected one of {sorted(config.outputs)}",
                               source=path)
        unit = (config.outputs[outcome.output].unit or "").strip()
        if outcome.statistic == "total" and normalise_unit(unit) in ("C", "K", "%"):
            raise BpsflowError(f"outcomes[{i}] ({outcome.name}).statistic: a total of "
                               f"'{outcome.output}' ({unit}) adds up a state, not a quantity; "
                               f"expected mean or discomfort for a {unit} output, or total of an "
                               f"energy (e.g. kWh)", source=path)
        if outcome.statistic == "discomfort" and normalise_unit(unit) != "C":
            raise BpsflowError(f"outcomes[{i}] ({outcome.name}): discomfort counts degree-hours "
                               f"under a setpoint, so its output must be a temperature in °C; "
                               f"'{outcome.output}' is in {unit or 'no unit'}", source=path)
        if outcome.setpoint is not None and outcome.setpoint.parameter is not None:
            names = [p.name for p in config.parameters]
            if outcome.setpoint.parameter not in names:
                raise BpsflowError(f"outcomes[{i}] ({outcome.name}).setpoint.parameter: unknown "
                                   f"parameter '{outcome.setpoint.parameter}'", source=path)
    week_start, week_end = week_dates(intervention, config, path)
    covering = []
    for test in config.model.tests:
        _, first, last = test_dates(test, config.model.year)
        if first <= week_start and week_end <= last:
            covering.append(test)
    if not covering:
        spans = ", ".join(f"{t.name} {d[1]:%m-%d}..{d[2]:%m-%d}" for t in config.model.tests
                          for d in [test_dates(t, config.model.year)])
        raise BpsflowError(f"week: {week_start:%m-%d}..{week_end:%m-%d} is not inside the "
                           f"evaluated days of any test of the config (evaluated: {spans})",
                           source=path)
    for i, outcome in enumerate(intervention.outcomes):
        if not any(outcome.output in test.outputs for test in covering):
            raise BpsflowError(
                f"outcomes[{i}] ({outcome.name}).output: no test evaluating the week outputs "
                f"'{outcome.output}' (test {', '.join(t.name for t in covering)} outputs "
                f"{sorted({o for t in covering for o in t.outputs})})", source=path)
    _every_outcome_counts_hours(intervention, week_start, week_end, path)
    return intervention


def _every_outcome_counts_hours(intervention: Intervention, week_start, week_end,
                                path: Path) -> None:
    """Refuse, before any simulation, an outcome whose hours miss every hour of the week."""
    hour_ends = pd.date_range(pd.Timestamp(week_start) + pd.Timedelta(hours=1),
                              pd.Timestamp(week_end) + pd.Timedelta(days=1), freq="h")
    for i, outcome in enumerate(intervention.outcomes):
        if not counted_hours(hour_ends, outcome.hours).any():
            hours = outcome.hours
            raise BpsflowError(
                f"outcomes[{i}] ({outcome.name}).hours: {hours.days} days "
                f"{hours.start_hour}-{hours.end_hour} h count no hour of the week "
                f"{week_start:%m-%d}..{week_end:%m-%d}", source=path)


def week_dates(intervention: Intervention, config: Config, source: Path | None = None):
    """First and last day of the intervention's test week."""
    from datetime import timedelta

    from bpsflow.config import _parse_month_day

    try:
        start = _parse_month_day(intervention.week.start, config.model.year)
    except ValueError as exc:
        raise BpsflowError(f"week.start: {exc}", source=source) from None
    return start, start + timedelta(days=intervention.week.days - 1)


def counted_hours(hour_ends: pd.DatetimeIndex, hours: Hours) -> np.ndarray:
    """Which hour-ending stamps fall in ``hours`` (judged by the hour each interval starts)."""
    starts = pd.DatetimeIndex(hour_ends) - pd.Timedelta(hours=1)
    weekend = starts.day_of_week >= 5
    day_ok = {"all": np.ones(len(starts), bool), "weekdays": ~weekend,
              "weekends": weekend}[hours.days]
    hour_ok = (starts.hour >= hours.start_hour) & (starts.hour < hours.end_hour)
    return np.asarray(day_ok & hour_ok)
