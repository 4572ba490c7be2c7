"""Schedule values per time step, read the way EnergyPlus reads them.

The surrogate evaluates the schedules its air-exchange and internal-gain
objects name: ``Schedule:Constant``, ``Schedule:Compact`` and ``Schedule:File``
(without interpolation). Timing follows EnergyPlus: the value of a time step
is the schedule's value at the step's *end* minute, so with ``Until: 09:00``
and ``Until: 17:00`` the second value applies to the steps ending after 09:00
up to and including 17:00 (the hours ending 10:00 ... 17:00).

Days of the week follow the calendar of ``model.year``: the instance writer
gives the run period's begin year and leaves "Day of Week for Start Day"
blank, so EnergyPlus takes the weekday of the real date; it uses no
weather-file holidays and the model declares no special days, so a day is
never a holiday, design day or custom day (``For: Holidays`` and the like
apply to no day of a run period).

``Schedule:File`` rows count hours from 1 January (row ``r`` covers the
hour ending at ``r + 1`` h), each day found by its month and day as
EnergyPlus does (:mod:`bpsflow.yearhours`: an 8760-hour file has no
29 February, an 8784-hour file has one); a relative file name was made
absolute against the file declaring the schedule by
:func:`bpsflow.simulation.idf.model_objects`. The run
periods use no daylight saving time, so "Adjust Schedule for Daylight
Savings" changes nothing.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import date, timedelta
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import IdfModel, IdfObject
from bpsflow.yearhours import LEAP_ROWS, NON_LEAP_ROWS, day_rows

#: Day types of a Schedule:Compact ``For:`` field that apply to a weekday (Monday = 0).
_WEEKDAY_NAMES = ("MONDAY", "TUESDAY", "WEDNESDAY", "THURSDAY", "FRIDAY", "SATURDAY", "SUNDAY")
#: Day types no day of a weather-file run period is (no holidays or special days).
_SPECIAL_DAY_TYPES = {"HOLIDAY", "HOLIDAYS", "SUMMERDESIGNDAY", "WINTERDESIGNDAY",
                      "CUSTOMDAY1", "CUSTOMDAY2"}
_SEPARATORS = {"COMMA": ",", "TAB": "\t", "SPACE": r"\s+", "SEMICOLON": ";"}
_MINUTES_PER_DAY = 1440


def day_type_matches(for_types: set[str], day: date) -> bool:
    """Whether a ``For:`` field's day types (upper case) cover ``day`` (not ``AllOtherDays``)."""
    weekday = day.weekday()
    if "ALLDAYS" in for_types or _WEEKDAY_NAMES[weekday] in for_types:
        return True
    if "WEEKDAYS" in for_types and weekday < 5:
        return True
    return "WEEKENDS" in for_types and weekday >= 5


def step_end_minutes(steps_per_hour: int) -> np.ndarray:
    """End minute (1..1440) of each time step of a day."""
    return np.arange(1, 24 * steps_per_hour + 1) * (60 // steps_per_hour)


@dataclass
class DaySchedule:
    """One day profile: value until each end minute (``Until: HH:MM``), no interpolation."""

    until_minutes: np.ndarray   # increasing, last = 1440
    values: np.ndarray

    def at(self, minutes: np.ndarray) -> np.ndarray:
        """Value at each step-end minute."""
        return self.values[np.searchsorted(self.until_minutes, minutes, side="left")]


@dataclass
class Schedule:
    """A schedule the surrogate can evaluate; :meth:`steps` gives its per-step values."""

    name: str
    kind: str                               # constant | compact | file
    constant: float = 1.0
    #: compact: (through month, through day, [(day types, DaySchedule), ...])
    periods: list[tuple[int, int, list[tuple[set[str], DaySchedule]]]] | None = None
    #: file: where and how to read the column
    file: Path | None = None
    column: int = 1
    skip_rows: int = 0
    separator: str = ","
    minutes_per_item: int = 60
    hours_of_data: int = 8760
    where: str = ""                         # "Schedule:File 'Name' (declared in ...)"

    @property
    def is_always_one(self) -> bool:
        return self.kind == "constant" and self.constant == 1.0

    def steps(self, first: date, days: int, steps_per_hour: int) -> np.ndarray:
        """Value of every time step of ``days`` days from ``first``, ``(days * 24 * tph,)``."""
        count = days * 24 * steps_per_hour
        if self.kind == "constant":
            return np.full(count, self.constant)
        if self.kind == "compact":
            minutes = step_end_minutes(steps_per_hour)
            return np.concatenate([self._day(first + timedelta(days=d)).at(minutes)
                                   for d in range(days)])
        return self._file_steps(first, days, steps_per_hour)

    def _day(self, day: date) -> DaySchedule:
        for month, last_day, rules in self.periods:
            if (day.month, day.day) <= (month, last_day):
                for types, profile in rules:
                    if "ALLOTHERDAYS" in types or day_type_matches(types, day):
                        return profile
                raise BpsflowError(f"{self.where}: no 'For:' field covers {day:%A %m/%d}")
        raise BpsflowError(f"{self.where}: its last 'Through:' ends before {day:%m/%d}")

    def _file_steps(self, first: date, days: int, steps_per_hour: int) -> np.ndarray:
        column = _read_column(self.file, *_stamp(self.file), self.column, self.skip_rows,
                              self.separator, self.where)
        items = self.hours_of_data * 60 // self.minutes_per_item
        if len(column) < items:
            raise BpsflowError(f"{self.where}: {self.file} has {len(column)} value(s) in column "
                               f"{self.column} after {self.skip_rows} skipped row(s); expected "
                               f"{items} ({self.hours_of_data} h at {self.minutes_per_item} min)")
        # EnergyPlus gives a file of fewer than 8784 hours no 29 February
        calendar = LEAP_ROWS if self.hours_of_data >= LEAP_ROWS else NON_LEAP_ROWS
        day_start = day_rows(first, days, calendar) * 60   # minutes since the file's start
        ends = (day_start[:, None] + step_end_minutes(steps_per_hour)[None, :]).ravel()
        # The item holding each step's end minute: items cover (k m, (k + 1) m].
        index = -(-ends // self.minutes_per_item) - 1
        if index.max() >= items:
            raise BpsflowError(f"{self.where}: the run period reaches past the file's "
                               f"{self.hours_of_data} hours")
        return column[index]


def _stamp(path: Path) -> tuple[int, int]:
    try:
        stat = Path(path).stat()
    except OSError:
        return (0, 0)
    return stat.st_mtime_ns, stat.st_size


@lru_cache(maxsize=16)
def _read_column(path: Path, mtime_ns: int, size: int, column: int, skip_rows: int,
                 separator: str, where: str) -> np.ndarray:
    if not Path(path).is_file():
        raise BpsflowError(f"{where}: schedule file not found: {path}")
    try:
        frame = pd.read_csv(path, sep=separator, header=None, skiprows=skip_rows,
                            usecols=[column - 1], engine="python" if len(separator) > 1 else "c")
    except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise BpsflowError(f"{where}: cannot read column {column} of {path}: {exc}") from None
    values = pd.to_numeric(frame.iloc[:, 0], errors="coerce").to_numpy(dtype=float)
    if np.isnan(values).any():
        row = int(np.flatnonzero(np.isnan(values))[0]) + skip_rows + 1
        raise BpsflowError(f"{where}: {path} row {row}, column {column}: not a number")
    values.setflags(write=False)
    return values


def _where(obj: IdfObject) -> str:
    return f"{obj.where} (in {obj.source})" if obj.source else obj.where


def _number(obj: IdfObject, field: str, default: float) -> float:
    try:
        return obj.number(field, default)
    except BpsflowError as exc:
        raise BpsflowError(f"{_where(obj)}: {exc.message}") from None


def read_schedule(idf: IdfModel, name: str, used_by: str) -> Schedule:
    """Parse the schedule ``name`` (blank: always 1) for the object ``used_by``.

    Raises
    ------
    BpsflowError
        When no schedule of a supported type has that name (naming ``used_by``),
        or the schedule uses what the surrogate does not model (interpolation,
        Schedule:File minutes per item that do not divide an hour).
    """
    if not name.strip():
        return Schedule(name="", kind="constant", constant=1.0)
    for object_type in ("SCHEDULE:CONSTANT", "SCHEDULE:COMPACT", "SCHEDULE:FILE"):
        for obj in idf.of_type(object_type):
            if obj.name.upper() == name.strip().upper():
                return _parse(obj)
    others = [o.spelling for o in idf.objects
              if o.type.startswith("SCHEDULE:") and o.name.upper() == name.strip().upper()]
    if others:
        raise BpsflowError(f"{used_by}: its schedule '{name}' is a {others[0]}; the surrogate "
                           f"reads Schedule:Constant, Schedule:Compact and Schedule:File")
    raise BpsflowError(f"{used_by}: no schedule named '{name}' in the model")


def _parse(obj: IdfObject) -> Schedule:
    where = _where(obj)
    if obj.type == "SCHEDULE:CONSTANT":
        return Schedule(name=obj.name, kind="constant", where=where,
                        constant=_number(obj, "Hourly Value", 0.0))
    if obj.type == "SCHEDULE:COMPACT":
        return Schedule(name=obj.name, kind="compact", where=where,
                        periods=_compact_periods(obj, where))
    interpolate = obj.get("Interpolate to Timestep").strip().upper() or "NO"
    if interpolate != "NO":
        raise BpsflowError(f"{where}: field 'Interpolate to Timestep' is {interpolate}; the "
                           f"surrogate reads Schedule:File values without interpolation (No)")
    separator = obj.get("Column Separator").strip().upper() or "COMMA"
    if separator not in _SEPARATORS:
        raise BpsflowError(f"{where}: field 'Column Separator' is '{separator}', expected one "
                           f"of Comma, Tab, Space, Semicolon")
    minutes = int(_number(obj, "Minutes per Item", 60))
    if minutes <= 0 or 60 % minutes:
        raise BpsflowError(f"{where}: field 'Minutes per Item' is {minutes}; expected a "
                           f"divisor of 60")
    file_name = obj.get("File Name").strip()
    if not file_name:
        raise BpsflowError(f"{where}: field 'File Name' is blank")
    return Schedule(name=obj.name, kind="file", where=where, file=Path(file_name),
                    column=int(_number(obj, "Column Number", 1)),
                    skip_rows=int(_number(obj, "Rows to Skip at Top", 0)),
                    separator=_SEPARATORS[separator], minutes_per_item=minutes,
                    hours_of_data=int(_number(obj, "Number of Hours of Data", 8760)))


_THROUGH = re.compile(r"^THROUGH:\s*(\d{1,2})\s*/\s*(\d{1,2})$")
_UNTIL = re.compile(r"^UNTIL:\s*(\d{1,2}):(\d{2})$")


def _compact_periods(obj: IdfObject, where: str):
    """``Through:`` blocks of a Schedule:Compact, each with its ``For:`` rules in order."""
    tokens = obj.fields[2:]
    periods: list[tuple[int, int, list[tuple[set[str], DaySchedule]]]] = []
    rules: list[tuple[set[str], list[tuple[int, float]]]] | None = None
    i = 0
    while i < len(tokens):
        token = tokens[i].strip()
        upper = re.sub(r"\s+", " ", token.upper())
        if not token:
            i += 1
            continue
        if (match := _THROUGH.match(upper)) is not None:
            rules = []
            periods.append((int(match[1]), int(match[2]), rules))  # type: ignore[arg-type]
        elif upper.startswith("FOR:") or upper.startswith("FOR "):
            if rules is None:
                raise BpsflowError(f"{where}: 'For:' field {i + 3} before any 'Through:'")
            types = set(upper[4:].replace(":", " ").split())
            unknown = types - {"ALLDAYS", "ALLOTHERDAYS", "WEEKDAYS", "WEEKENDS",
                               *_WEEKDAY_NAMES, *_SPECIAL_DAY_TYPES}
            if unknown or not types:
                raise BpsflowError(f"{where}: field {i + 3} '{token}' names unknown day "
                                   f"type(s) {sorted(unknown) or '(none)'}")
            rules.append((types, []))
        elif upper.startswith("INTERPOLATE:"):
            choice = upper.split(":", 1)[1].strip()
            if choice != "NO":
                raise BpsflowError(f"{where}: field {i + 3} '{token}': the surrogate models "
                                   f"Interpolate:No only")
        elif (match := _UNTIL.match(upper)) is not None:
            if not rules:
                raise BpsflowError(f"{where}: 'Until:' field {i + 3} before any 'For:'")
            if i + 1 >= len(tokens):
                raise BpsflowError(f"{where}: 'Until:' field {i + 3} has no value after it")
            minute = int(match[1]) * 60 + int(match[2])
            try:
                value = float(tokens[i + 1])
            except ValueError:
                raise BpsflowError(f"{where}: field {i + 4} '{tokens[i + 1]}' after "
                                   f"'{token}' is not a number") from None
            rules[-1][1].append((minute, value))
            i += 1
        else:
            raise BpsflowError(f"{where}: field {i + 3} '{token}' is not a Through:, For:, "
                               f"Interpolate: or Until: field")
        i += 1
    if not periods:
        raise BpsflowError(f"{where}: no 'Through:' field")
    out = []
    for month, day, day_rules in periods:
        profiles = []
        for types, intervals in day_rules:
            minutes = [m for m, _ in intervals]
            if not intervals or minutes[-1] != _MINUTES_PER_DAY or np.any(np.diff(minutes) <= 0):
                raise BpsflowError(f"{where}: the 'Until:' times of 'For: "
                                   f"{' '.join(sorted(types))}' must increase and end at 24:00")
            profiles.append((types, DaySchedule(np.array(minutes), np.array(
                [v for _, v in intervals], dtype=float))))
        out.append((month, day, profiles))
    return out
