"""Measured data: the one reader every command that takes ``--measured`` goes through.

Format
------
A UTF-8 CSV with a header line. One column is ``timestamp``; the others are
named like the config's outputs (``heating_power_w``), in the output's
declared ``unit``. Other numeric columns are kept (``bpsflow diagnose`` tries
them as drivers); other text columns are left out, with a note. An empty cell
is a missing value; the texts ``nan``, ``inf`` and ``-inf`` are errors (leave
the cell empty instead). Numbers with thousands separators (quoted
``"1,234.5"``, ``"1,234,567"``) are read as such, with a note; ``"1,234"``
(a thousands separator or a decimal comma?) and ``"27,5"`` are errors.

Timestamps are hour-ENDING, like the simulated results (the value at 01:00
covers 00:00–01:00; EnergyPlus reports the same way, see
:mod:`bpsflow.alignment`), in the model's local standard time. Stamps with a
UTC offset (``2025-12-05T01:00:00+01:00``) are converted, each by its own
offset, to the model's standard time, which is the time zone of the weather
file's ``LOCATION`` header (field 9, hours from UTC); mixed offsets (daylight
saving time) are therefore converted row by row, never shifted as a block.
Files that mix stamps with and without an offset are refused. Unsorted stamps
are sorted (with a note); a repeated stamp is an error.

Rows outside every test window (a test's days, warm-up included) are left out
with a note; a file with no row in any window is an error.

Resolution
----------
The model reports hourly (an output with ``frequency: timestep`` at every
zone time step, ``60 / model.timesteps_per_hour`` minutes). Finer measured data
are aggregated to the output's resolution into hour-ending (step-ending) bins,
so 00:15, 00:30, 00:45 and 01:00 make the hour ending 01:00. The rule follows
the output's declared unit:

* mean for powers, temperatures and shares: ``W``, ``kW``, ``MW``, ``W/m2``,
  ``C``/``°C``, ``K``, ``%`` (and for columns that are not outputs);
* sum for energies: ``J``, ``kJ``, ``MJ``, ``GJ``, ``Wh``, ``kWh``, ``MWh``.

A bin missing some of its sub-steps (a missing row or an empty cell) is left
out (not averaged from fewer values); the note counts them. A step the tool
cannot aggregate is an error naming the file and the step: irregular steps,
stamps off the step's grid, a step that does not divide the output's
resolution, or a step coarser than it. An output of another unit cannot be
aggregated (no rule): declare its unit.

Plausibility
------------
Values far outside a physical range for the declared unit are an error naming
the column, the first bad line, the range and the likely unit mistake:

* ``C``/``°C``: [-60, 100]; ``K``: [200, 380]; ``%``: [-5, 105];
* powers and energies (``W``, ``kWh``, ...): at most 20 times the largest
  magnitude the simulated ensemble reports for that output, when results are
  at hand (a ×1000 unit mistake is far above; an ensemble that is all zero
  sets no ceiling). Without results, no ceiling is applied.

``outputs.NAME.plausible: [low, high]`` in the config replaces the range of an
output (``[0, null]``: non-negative, no ceiling; ``[null, null]``: unchecked);
``--allow-implausible`` turns these errors into notes for one command.
"""

from __future__ import annotations

import csv
import difflib
import io
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, test_dates
from bpsflow.errors import BpsflowError

TIMESTAMP_COLUMN = "timestamp"

#: Units aggregated by the mean of their sub-steps (rates and states), upper case.
MEAN_UNITS = frozenset({"W", "KW", "MW", "W/M2", "W/M²", "C", "°C", "DEGC", "K", "%"})
#: Units aggregated by the sum of their sub-steps (energies per step), upper case.
SUM_UNITS = frozenset({"J", "KJ", "MJ", "GJ", "WH", "KWH", "MWH"})
#: Physical ranges (low, high) per unit, upper case; powers and energies are relative.
PHYSICAL_RANGES: dict[str, tuple[float, float]] = {
    "C": (-60.0, 100.0), "°C": (-60.0, 100.0), "DEGC": (-60.0, 100.0),
    "K": (200.0, 380.0), "%": (-5.0, 105.0)}
#: Ceiling of a power or energy: this many times the ensemble's largest magnitude.
RELATIVE_CEILING = 20.0
#: Floor of a power or energy the simulations never make negative: minus this share of their
#: largest magnitude (meter noise around zero passes, a reversed sign does not).
NEGATIVE_SHARE = 0.1

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_NON_FINITE = re.compile(r"^[+-]?(nan|inf|infinity)$", re.IGNORECASE)
_THOUSANDS = re.compile(r"^[+-]?\d{1,3}(,\d{3})+\.\d*$|^[+-]?\d{1,3}(,\d{3}){2,}$")
_AMBIGUOUS_COMMA = re.compile(r"^[+-]?\d{1,3},\d{3}$")
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+$")
#: A time of day, then a zone designator: ``Z``/``z``, ``UTC``/``GMT``, or ``±hh``, ``±hhmm``,
#: ``±hh:mm`` (ISO 8601 allows hours alone). Group 1 is the stamp, group 2 the designator.
_OFFSET = re.compile(r"^(.*[T ]\d{2}(?::?\d{2}){0,2}(?:[.,]\d+)?)\s*"
                     r"(Z|z|UTC|GMT|[+-]\d{2}(?::?\d{2})?)$")


@dataclass(frozen=True)
class MeasuredData:
    """Measured values ready for the commands, and what was done to read them.

    Attributes
    ----------
    frame : DataFrame
        Index: hour-ending (step-ending) timestamps, naive, in the model's
        local standard time, sorted and unique. Columns: the file's numeric
        columns as floats, at the resolution of the output they name.
    source : Path
        The file read.
    notes : tuple of str
        What the user must know (aggregation, conversion, rows left out),
        each naming the file; the commands print them.
    aggregation : dict
        Column -> how it was aggregated (``"15-min data averaged to hourly"``), for
        the columns that were.
    """

    frame: pd.DataFrame
    source: Path
    notes: tuple[str, ...] = ()
    aggregation: dict[str, str] = field(default_factory=dict)

    def note_for(self, column: str) -> str:
        """The aggregation applied to ``column`` as a short note ("" if none)."""
        rule = self.aggregation.get(column)
        return f"measured: {rule}" if rule else ""

    def record(self) -> dict:
        """What ``validation.json`` records about the measured file."""
        return {"file": str(self.source.resolve()), "notes": list(self.notes),
                "aggregation": dict(self.aggregation)}


def read_measured(path: Path | str, config: Config, *, required: Sequence[str] | None = None,
                  reference: pd.DataFrame | None = None,
                  allow_implausible: bool = False) -> MeasuredData:
    """Read, check and aggregate a measured data file (see the module docstring).

    Parameters
    ----------
    path : Path or str
        The CSV file.
    config : Config
        Its outputs (names, units, resolution, plausible ranges), tests
        (windows) and weather file (time zone).
    required : sequence of str, optional
        Output columns the command needs; by default at least one of the
        config's outputs.
    reference : DataFrame, optional
        Tidy simulated results (``output``, ``value``) that set the ceiling
        of powers and energies.
    allow_implausible : bool
        Report values outside their plausible range as notes, not errors.

    Returns
    -------
    MeasuredData

    Raises
    ------
    BpsflowError
        One error naming the file, the column and the first bad line
        (1-based, the header is line 1) for any problem of the file.
    """
    path = Path(path)
    notes: list[str] = []
    header, rows, lines = _csv_rows(_read_text(path), path, notes)
    stamp_column = _timestamp_column(header, path)
    columns = _value_columns(header, stamp_column, config, required, path, notes)
    table = {name: [row[i] for row in rows] for i, name in enumerate(header)}
    stamps = _parse_stamps(table[stamp_column], lines, config, path, notes)
    values = {}
    for name in columns:
        parsed = _parse_values(table[name], lines, name, path, notes,
                               strict=name in config.outputs)
        if parsed is not None:
            values[name] = parsed
    frame = pd.DataFrame(values, index=stamps)
    frame, lines = _sorted_unique(frame, lines, path, notes)
    _check_plausible(frame, lines, config, reference, allow_implausible, path, notes)
    frame = _keep_test_windows(frame, config, path, notes)
    frame, aggregation = _aggregate(frame, config, path, notes)
    # after aggregation: 5-min energy readings are rightly far smaller than hourly sums
    _check_scale(frame, config, reference, allow_implausible, path, notes)
    frame.index.name = TIMESTAMP_COLUMN
    return MeasuredData(frame=frame, source=path, notes=tuple(notes), aggregation=aggregation)


def plausibility_reference(run_dir: Path) -> pd.DataFrame | None:
    """The run directory's simulated results for the plausibility ceiling, if any are readable."""
    from bpsflow.simulation.rundir import read_results

    try:
        return read_results(run_dir)
    except BpsflowError:
        return None


def output_resolution(config: Config, column: str) -> pd.Timedelta:
    """The model's reporting step for ``column``: an hour, or a zone time step."""
    output = config.outputs.get(column)
    if output is not None and output.frequency == "timestep":
        return pd.Timedelta(minutes=60 / config.model.timesteps_per_hour)
    return pd.Timedelta(hours=1)


def aggregation_rule(unit: str) -> str | None:
    """``"mean"`` or ``"sum"`` for a declared unit, None when the unit has no rule."""
    key = unit.strip().upper()
    if key in MEAN_UNITS:
        return "mean"
    if key in SUM_UNITS:
        return "sum"
    return None


# Reading the file ----------------------------------------------------------

def _read_text(path: Path) -> str:
    """The file's text; a clear error for missing, empty, compressed or binary files."""
    if not path.exists():
        raise BpsflowError(f"measured data file not found: {path}")
    if not path.is_file():
        raise BpsflowError("measured data must be a CSV file, not a folder", source=path)
    data = path.read_bytes()
    if not data.strip():
        raise BpsflowError("the measured data file is empty; expected a header line "
                           "'timestamp,<output>,...' and one row per time step", source=path)
    if data[:2] == b"\x1f\x8b":
        raise BpsflowError("this is a gzip-compressed file; decompress it and pass the CSV",
                           source=path)
    if data[:4] == b"PK\x03\x04":
        raise BpsflowError("this is a ZIP archive (or a spreadsheet); export the sheet as CSV",
                           source=path)
    if b"\x00" in data:
        line = data[:data.index(b"\x00")].count(b"\n") + 1
        raise BpsflowError(f"line {line}: binary content (a NUL byte); expected CSV text",
                           source=path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise BpsflowError(f"line {line}: not UTF-8 text (byte 0x{data[exc.start]:02x}); "
                           f"expected a CSV file saved as UTF-8", source=path) from None


#: Field separators of other CSV dialects, for the hint when a header holds one of them.
OTHER_SEPARATORS = {";": "';' (with decimal commas?)", "\t": "tabs", "|": "'|'"}


def _csv_rows(text: str, path: Path, notes: list[str]
              ) -> tuple[list[str], list[list[str]], np.ndarray]:
    """Header, data rows and each row's 1-based line number.

    Blank lines are skipped, and so are comment lines (first field starting
    with ``#``, as data loggers write above the header), with a note.
    """
    reader = csv.reader(io.StringIO(text, newline=""))
    header: list[str] | None = None
    rows: list[list[str]] = []
    lines: list[int] = []
    comments: list[int] = []
    try:
        for record in reader:
            if not record or all(not cell.strip() for cell in record):
                continue
            if record[0].lstrip().startswith("#"):
                comments.append(reader.line_num)
                continue
            if header is None:
                header = [cell.strip() for cell in record]
                header_line = reader.line_num
                separator = next((name for mark, name in OTHER_SEPARATORS.items()
                                  if len(header) == 1 and mark in header[0]), None)
                if separator:
                    raise BpsflowError(f"line {header_line}: the header is one field: the file "
                                       f"is separated by {separator}; "
                                       f"expected commas between fields and points in numbers "
                                       f"(e.g. export as CSV with an English locale)",
                                       source=path)
                continue
            if len(record) != len(header):
                hint = ""
                if len(header) == 1 and ";" in header[0]:
                    hint = ("; the file is separated by ';' (with decimal commas?): expected "
                            "commas between fields and points in numbers (e.g. export as CSV "
                            "with an English locale)")
                raise BpsflowError(f"line {reader.line_num}: {len(record)} fields, but the header "
                                   f"(line {header_line}) has {len(header)}{hint}", source=path)
            rows.append(record)
            lines.append(reader.line_num)
    except csv.Error as exc:
        raise BpsflowError(f"line {reader.line_num}: not valid CSV ({exc})", source=path) from None
    if comments:
        notes.append(f"{path.name}: {len(comments)} comment line(s) starting with '#' skipped "
                     f"(line {comments[0]}" + (f" .. {comments[-1]})" if len(comments) > 1
                                               else ")"))
    if header is None:
        raise BpsflowError("the measured data file has no header line", source=path)
    if not rows:
        raise BpsflowError(f"the measured data file has a header but no data rows (columns: "
                           f"{', '.join(header)})", source=path)
    return header, rows, np.asarray(lines)


def _timestamp_column(header: list[str], path: Path) -> str:
    """The header's ``timestamp`` column (case-insensitive); errors for none or repeats."""
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise BpsflowError(f"line 1: column '{name}' appears twice in the header", source=path)
        seen.add(name)
    matches = [name for name in header if name.lower() == TIMESTAMP_COLUMN]
    if not matches:
        hint = (" (the file looks separated by ';': expected ',')"
                if len(header) == 1 and ";" in header[0] else "")
        raise BpsflowError(f"line 1: no '{TIMESTAMP_COLUMN}' column (columns: "
                           f"{', '.join(header)}){hint}", source=path)
    return matches[0]


def _value_columns(header: list[str], stamp_column: str, config: Config,
                   required: Sequence[str] | None, path: Path, notes: list[str]) -> list[str]:
    """The value columns; errors when a required output (or every output) is missing."""
    columns = [name for name in header if name != stamp_column]
    unnamed = [i + 1 for i, name in enumerate(header) if not name.strip()]
    if unnamed:
        # a row index written beside the data (pandas' to_csv) is no measurement
        notes.append(f"{path.name}: column(s) {', '.join(map(str, unnamed))} of line 1 have no "
                     f"name (a row index written with the data?): left out")
        columns = [name for name in columns if name.strip()]
    unknown = [name for name in columns if name not in config.outputs]
    needed = list(required) if required is not None else []
    missing = [name for name in needed if name not in columns]
    if missing or not any(name in config.outputs for name in columns):
        wanted = missing or sorted(config.outputs)
        what = (f"no column '{missing[0]}'" + (f" (nor {', '.join(missing[1:])})"
                                              if len(missing) > 1 else "")
                if missing else "none of the config's outputs")
        raise BpsflowError(f"line 1: {what}; columns: {', '.join(columns) or 'none'}; expected "
                           f"output(s) {', '.join(wanted)}{_suggestion(wanted, unknown)}",
                           source=path)
    for name in unknown:
        close = difflib.get_close_matches(name, list(config.outputs), n=1, cutoff=0.8)
        if close and close[0] not in columns:
            # the output it stands for is absent: a misspelling, whatever the command needs
            raise BpsflowError(f"line 1: column '{name}' is not an output; did you mean "
                               f"'{close[0]}'? (columns: {', '.join(columns)})", source=path)
        if close:
            notes.append(f"{path.name}: column '{name}' is not an output (close to "
                         f"'{close[0]}', which is also there); read as an extra column")
    return columns


def _suggestion(wanted: Iterable[str], unknown: list[str]) -> str:
    """``"; 'heating_power_W' looks like 'heating_power_w'"`` for close misspellings."""
    pairs = []
    for name in wanted:
        close = difflib.get_close_matches(name, unknown, n=1, cutoff=0.6)
        if close:
            pairs.append(f"'{close[0]}' looks like '{name}' (misspelled?)")
    return "; " + ", ".join(pairs) if pairs else ""


# Timestamps ---------------------------------------------------------------

def _parse_stamps(texts: list[str], lines: np.ndarray, config: Config, path: Path,
                  notes: list[str]) -> pd.DatetimeIndex:
    """Naive timestamps in the model's local standard time (UTC offsets converted)."""
    series = pd.Series(texts, dtype=object).str.strip()
    parts = series.str.extract(_OFFSET)
    offsets = parts[1].map(_iso_offset, na_action="ignore")
    aware = offsets.notna().to_numpy()
    if aware.any() and not aware.all():
        first = int(np.flatnonzero(~aware if aware[0] else aware)[0])
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}', line {lines[first]}: "
                           f"'{texts[first]}' {'has no' if aware[0] else 'has a'} UTC offset "
                           f"but line {lines[0]} {'has one' if aware[0] else 'does not'}; "
                           f"expected one convention for every stamp", source=path)
    if aware.any():
        # one spelling of every designator (hours alone, UTC, lower-case z), so that the
        # parser applies each offset rather than reading a stamp it does not know as UTC
        series = parts[0] + offsets
    parsed = pd.to_datetime(series, format="ISO8601", errors="coerce", utc=True)
    if not aware.any():
        parsed = parsed.dt.tz_localize(None)
        if parsed.isna().any():
            parsed = _parse_local_format(series, lines, path, notes)
    bad = np.flatnonzero(parsed.isna().to_numpy())
    if len(bad):
        zone_name = (" (time-zone names are not read: write a UTC offset such as -08:00, or "
                     "the model's local standard time without one)"
                     if re.search(r"\d\s*[A-Za-z]{2,5}$", texts[bad[0]].strip()) else "")
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}', line {lines[bad[0]]}: "
                           f"'{texts[bad[0]]}' is not a date and time (expected e.g. "
                           f"2025-12-05 01:00:00, hour-ending){zone_name}", source=path)
    if not aware.any():
        return pd.DatetimeIndex(parsed)
    hours = model_utc_offset(config, path)
    local = parsed.dt.tz_convert(None) + pd.Timedelta(hours=hours)
    found = sorted(set(offsets))
    dst = (" (more than one offset, e.g. daylight saving time: each stamp converted by its "
           "own)" if len(found) > 1 else "")
    notes.append(f"{path.name}: timestamps with UTC offset {', '.join(found)} converted to the "
                 f"model's local standard time (UTC{_format_offset(hours)}, the weather "
                 f"file's time zone){dst}")
    return pd.DatetimeIndex(local)


def _iso_offset(designator: str) -> str:
    """``±hh:mm`` for a zone designator (``Z``, ``z``, ``UTC``, ``GMT``, ``±hh``, ``±hhmm``)."""
    if designator.upper() in ("Z", "UTC", "GMT"):
        return "+00:00"
    digits = designator[1:].replace(":", "")
    return f"{designator[0]}{digits[:2]}:{digits[2:] or '00'}"


def _parse_local_format(series: pd.Series, lines: np.ndarray, path: Path,
                        notes: list[str]) -> pd.Series:
    """Stamps not in ISO 8601 (e.g. ``12/05/2025 01:00``), read with ONE format for every row.

    The format is inferred from the first stamp, once month-first and once
    day-first. When both read every row but disagree, the file is ambiguous
    and refused: guessing row by row would read 05/12 as May and 13/12 as
    December in one column.
    """
    import warnings

    readings = {}
    for dayfirst in (False, True):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            readings[dayfirst] = pd.to_datetime(series, dayfirst=dayfirst, errors="coerce")
    complete = [dayfirst for dayfirst, parsed in readings.items() if not parsed.isna().any()]
    if len(complete) == 2 and not readings[False].equals(readings[True]):
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}', line {lines[0]}: '{series.iloc[0]}' "
                           f"reads as day/month and as month/day; write stamps as ISO 8601 "
                           f"(2025-12-05 01:00:00)", source=path)
    if not complete:
        return readings[False]
    order = "day/month" if complete == [True] else "month/day"
    notes.append(f"{path.name}: timestamps are not ISO 8601; read as {order} for every row")
    return readings[complete[0]]


def model_utc_offset(config: Config, source: Path) -> float:
    """The model's standard time zone in hours from UTC (EPW ``LOCATION`` field 9).

    Raises
    ------
    BpsflowError
        When the weather file does not state it: time-zone-aware stamps are
        then refused (``source`` names the measured file).
    """
    from bpsflow.weather import read_epw

    try:
        fields = read_epw(config.model.weather).header[0].split(",")
        hours = float(fields[8])
    except (BpsflowError, IndexError, ValueError):
        raise BpsflowError(f"timestamps carry a UTC offset, but the model's time zone is not "
                           f"known (the weather file {config.model.weather} states none in its "
                           f"LOCATION line, field 9); write the stamps in the model's local "
                           f"standard time without an offset", source=source) from None
    if not -12.0 <= hours <= 14.0:
        raise BpsflowError(f"timestamps carry a UTC offset, but the weather file's time zone "
                           f"({hours:g} h, LOCATION field 9) is not a UTC offset; write the "
                           f"stamps in local standard time without an offset", source=source)
    return hours


def _format_offset(hours: float) -> str:
    sign = "+" if hours >= 0 else "-"
    minutes = round(abs(hours) * 60)
    return f"{sign}{minutes // 60:02d}:{minutes % 60:02d}"


def _sorted_unique(frame: pd.DataFrame, lines: np.ndarray, path: Path,
                   notes: list[str]) -> tuple[pd.DataFrame, np.ndarray]:
    """Error on a repeated stamp; sort unsorted stamps (with a note)."""
    repeated = frame.index.duplicated(keep="first")
    if repeated.any():
        i = int(np.flatnonzero(repeated)[0])
        first = int(np.flatnonzero(frame.index == frame.index[i])[0])
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}', line {lines[i]}: {frame.index[i]} "
                           f"repeats line {lines[first]}; expected one row per time step",
                           source=path)
    if frame.index.is_monotonic_increasing:
        return frame, lines
    step_back = int(np.flatnonzero(np.diff(frame.index.asi8) < 0)[0]) + 1
    notes.append(f"{path.name}: timestamps are not in order (line {lines[step_back]} goes back "
                 f"in time); rows sorted by time")
    order = np.argsort(frame.index.asi8, kind="stable")
    return frame.iloc[order], lines[order]


# Values --------------------------------------------------------------------

def _parse_values(texts: list[str], lines: np.ndarray, column: str, path: Path,
                  notes: list[str], strict: bool) -> np.ndarray | None:
    """A column's numbers (empty cells NaN).

    ``strict`` (an output's column): anything else is an error naming the
    first bad line. Otherwise a column that is not numeric is left out with a
    note (returns None).
    """
    cells = pd.Series(texts, dtype=object).str.strip()
    empty = (cells == "").to_numpy()
    number = cells.str.fullmatch(_NUMBER).to_numpy(dtype=bool)
    thousands = cells.str.fullmatch(_THOUSANDS).to_numpy(dtype=bool)
    bad = np.flatnonzero(~(empty | number | thousands))
    if len(bad):
        text = texts[bad[0]].strip()
        if not strict:
            notes.append(f"{path.name}: column '{column}' is not an output and not numeric "
                         f"(line {lines[bad[0]]}: '{text}'); left out")
            return None
        raise BpsflowError(f"column '{column}', line {lines[bad[0]]}: {_why_not_number(text)}",
                           source=path)
    values = np.full(len(cells), np.nan)
    values[number] = cells[number].astype(float).to_numpy()
    overflow = np.flatnonzero(np.isinf(values))
    if len(overflow):
        # 1e309 is written as a number but is beyond any float: it reads as infinity
        text = texts[overflow[0]].strip()
        if not strict:
            notes.append(f"{path.name}: column '{column}' is not an output and holds a number "
                         f"beyond the float range (line {lines[overflow[0]]}: '{text}'); "
                         "left out")
            return None
        raise BpsflowError(f"column '{column}', line {lines[overflow[0]]}: '{text}' is beyond "
                           "the range of a number (about ±1.8e308); expected a finite value",
                           source=path)
    if thousands.any():
        values[thousands] = cells[thousands].str.replace(",", "").astype(float).to_numpy()
        first = int(np.flatnonzero(thousands)[0])
        notes.append(f"{path.name}: column '{column}': {int(thousands.sum())} value(s) with "
                     f"thousands separators read as numbers (line {lines[first]}: "
                     f"'{texts[first].strip()}' -> {values[first]:g})")
    return values


def _why_not_number(text: str) -> str:
    if _NON_FINITE.match(text):
        return (f"'{text}' is not a finite number; leave the cell empty for a missing value")
    if _AMBIGUOUS_COMMA.match(text):
        return (f"'{text}' is ambiguous (a thousands separator or a decimal comma?); write it "
                f"without the comma, with '.' as the decimal point")
    if _DECIMAL_COMMA.match(text):
        return f"'{text}' has a decimal comma; expected '.' as the decimal point"
    return f"'{text}' is not a number (expected a number, or an empty cell for a missing value)"


# Plausibility ---------------------------------------------------------------

def _check_plausible(frame: pd.DataFrame, lines: np.ndarray, config: Config,
                     reference: pd.DataFrame | None, allow: bool, path: Path,
                     notes: list[str]) -> None:
    """Error (or, with ``allow``, a note) for the first value far outside its range."""
    for column in frame.columns:
        if column not in config.outputs:
            continue
        low, high, why = plausible_range(config, column, reference)
        values = frame[column].to_numpy()
        outside = ((values < low) | (values > high)) & ~np.isnan(values)
        if not outside.any():
            continue
        i = int(np.flatnonzero(outside)[0])
        unit = config.outputs[column].unit
        _implausible(f"column '{column}' [{unit}], line {lines[i]}: {values[i]:g} is far outside "
                     f"the plausible range [{low:g}, {high:g}] ({why}; {int(outside.sum())} "
                     f"value(s) outside){_unit_mistake(values[i], low, high, unit)}",
                     column, allow, path, notes)


def _check_scale(frame: pd.DataFrame, config: Config, reference: pd.DataFrame | None,
                 allow: bool, path: Path, notes: list[str]) -> None:
    """Error (or a note) for a column far smaller than the simulations, at their resolution."""
    for column in frame.columns:
        if column in config.outputs:
            values = frame[column].to_numpy(dtype=float)
            message = _too_small(column, values, config.outputs[column].unit, config,
                                 reference) or \
                _temperature_offset(column, values, config.outputs[column].unit, config,
                                    reference)
            if message:
                _implausible(message, column, allow, path, notes)


def _implausible(message: str, column: str, allow: bool, path: Path, notes: list[str]) -> None:
    if not allow:
        raise BpsflowError(f"{message}. If the values are right, set outputs.{column}."
                           f"plausible: [low, high] in the config, or pass "
                           f"--allow-implausible", source=path)
    notes.append(f"{path.name}: {message} (accepted: --allow-implausible)")


def plausible_range(config: Config, column: str, reference: pd.DataFrame | None
                    ) -> tuple[float, float, str]:
    """(low, high, where it comes from) of an output's plausible values."""
    output = config.outputs[column]
    unit = output.unit.strip().upper()
    if output.plausible is not None:
        low, high = output.plausible
        return (-np.inf if low is None else low, np.inf if high is None else high,
                f"outputs.{column}.plausible")
    if unit in PHYSICAL_RANGES:
        low, high = PHYSICAL_RANGES[unit]
        return low, high, f"physical range for {output.unit}"
    if aggregation_rule(unit) is not None and reference is not None:
        scale = _ensemble_scale(reference, column)
        if scale > 0:
            ceiling = RELATIVE_CEILING * scale
            why = f"{RELATIVE_CEILING:g} × the largest simulated magnitude {scale:.4g}"
            if float(np.min(_ensemble_values(reference, column))) >= 0:
                # a heating or cooling rate the model never makes negative: measured values
                # well below zero are a sign convention (cooling as negative heating) or a fault
                return (-NEGATIVE_SHARE * scale, ceiling,
                        f"{why}; the simulations are never negative, so at least "
                        f"-{NEGATIVE_SHARE:g} × that magnitude")
            return -ceiling, ceiling, why
    return -np.inf, np.inf, "unchecked"


def _ensemble_values(reference: pd.DataFrame, column: str) -> np.ndarray:
    """The finite simulated values of ``column`` over the ensemble."""
    simulated = reference.loc[reference["output"] == column, "value"].to_numpy(dtype=float)
    return simulated[np.isfinite(simulated)]


def _ensemble_scale(reference: pd.DataFrame, column: str) -> float:
    """The largest finite magnitude of ``column`` over the simulated ensemble (0 if none)."""
    finite = _ensemble_values(reference, column)
    return float(np.max(np.abs(finite))) if finite.size else 0.0


#: Median difference (K) between a measured temperature and the simulations that no
#: calibration error explains: a unit mistake (°F, kelvin) or another sensor.
TEMPERATURE_OFFSET_K = 20.0


def _temperature_offset(column: str, values: np.ndarray, unit: str, config: Config,
                        reference: pd.DataFrame | None) -> str:
    """A message when a °C column sits far from every simulation ("" if not).

    °F readings of a room (60–90 °F) pass the physical range of °C; against the
    ensemble's median they are 20 K or more off, and their °C conversion is not.
    """
    if reference is None or config.outputs[column].plausible is not None \
            or unit.strip().upper() not in ("C", "°C", "DEGC"):
        return ""
    simulated, measured = _ensemble_values(reference, column), values[np.isfinite(values)]
    if not simulated.size or not measured.size:
        return ""
    offset = float(np.median(measured) - np.median(simulated))
    if abs(offset) <= TEMPERATURE_OFFSET_K:
        return ""
    hint = ""
    if abs(float(np.median((measured - 32.0) / 1.8) - np.median(simulated))) < abs(offset) / 3:
        hint = " (°F in a °C column?)"
    elif abs(float(np.median(measured - 273.15) - np.median(simulated))) < abs(offset) / 3:
        hint = " (kelvin in a °C column?)"
    return (f"column '{column}' [{unit}]: its median {np.median(measured):.4g} is "
            f"{offset:+.3g} K from the simulations' median {np.median(simulated):.4g}{hint}")


def _too_small(column: str, values: np.ndarray, unit: str, config: Config,
               reference: pd.DataFrame | None) -> str:
    """A message when a power or energy column is far smaller than every simulation ("" if not).

    Its largest magnitude below 1/:data:`RELATIVE_CEILING` of the ensemble's
    is a scale mistake (kWh in a J column) rather than a building that used
    almost nothing: every normalised metric of it would be meaningless. A
    column of zeros (no heating at all) is left alone.
    """
    if reference is None or config.outputs[column].plausible is not None \
            or aggregation_rule(unit.strip().upper()) is None:
        return ""
    measured_scale = float(np.nanmax(np.abs(values))) if np.isfinite(values).any() else 0.0
    scale = _ensemble_scale(reference, column)
    if not (measured_scale > 0 and scale > 0 and measured_scale * RELATIVE_CEILING < scale):
        return ""
    ratio = scale / measured_scale
    guesses = [(3.6e6, "kWh in a J column?"), (3600.0, "Wh in a J column?"),
               (1000.0, "kilo-units (kW, kWh) in a W or Wh column?"),
               (1e6, "mega-units (MJ, MW) in a J or W column?")]
    guess = min(guesses, key=lambda g: abs(np.log(ratio / g[0])))
    hint = f" ({guess[1]})" if abs(np.log(ratio / guess[0])) < np.log(3.0) else ""
    return (f"column '{column}' [{unit}]: its largest magnitude {measured_scale:.4g} is "
            f"{ratio:.3g} times smaller than the simulations' ({scale:.4g}){hint}")


def _unit_mistake(value: float, low: float, high: float, unit: str) -> str:
    """A guess at the unit mistake behind an implausible value ("" when none fits)."""
    key = unit.strip().upper()
    if key in ("C", "°C", "DEGC") and low <= value - 273.15 <= high:
        return "; kelvin in a °C column?"
    if key in ("C", "°C", "DEGC") and low <= (value - 32.0) / 1.8 <= high and value > high:
        return "; °F in a °C column?"
    if key == "K" and low <= value + 273.15 <= high:
        return "; °C in a kelvin column?"
    if value < 0 and low <= -value <= high and key not in ("C", "°C", "DEGC", "K"):
        return "; a reversed sign (heat or energy written as negative)?"
    candidates = [(1000.0, "×1000: milli-units (mK, mW) or a missing decimal point"),
                  (1e6, "×10⁶: a unit prefix mistake"),
                  (100.0, "×100: a missing decimal point")]
    if key == "W":
        # an hour's energy in J read as a mean power is 3600 times too large
        candidates.insert(0, (3600.0, "×3600: J per hour (an energy) in a W column"))
    fitting = [guess for factor, guess in candidates if low <= value / factor <= high]
    return f"; {' or '.join(fitting[:2])}?" if fitting else ""


# Windows and resolution -----------------------------------------------------

def _keep_test_windows(frame: pd.DataFrame, config: Config, path: Path,
                       notes: list[str]) -> pd.DataFrame:
    """Rows whose hour-ending bin lies in some test's days (warm-up included)."""
    year = config.model.year
    windows = []
    for test in config.model.tests:
        first, _, last = test_dates(test, year)
        windows.append((pd.Timestamp(first), pd.Timestamp(last) + pd.Timedelta(days=1)))
    bins = frame.index.ceil("h")
    inside = np.zeros(len(frame), bool)
    for start, end in windows:
        inside |= (bins > start) & (bins <= end)
    if inside.all():
        return frame
    expected = "; ".join(f"{t.name}: {s} .. {e}" for t, (s, e) in zip(config.model.tests, windows))
    starts = {start for start, _ in windows}
    ends = {end for _, end in windows}
    step = _file_step(frame.index, path)
    if (inside.any() and step is not None and all(b in starts for b in bins[~inside])
            and frame.index[-1] + step in ends):
        # left out only at a window's first instant, and one step short of a window's end:
        # every stamp marks the start of its interval, and reading them as ends shifts the data
        shift = ("one hour" if step == pd.Timedelta(hours=1)
                 else f"{step / pd.Timedelta(minutes=1):g} minutes")
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}': the stamps look hour-beginning (the "
                           f"file runs from {frame.index[0]} to {frame.index[-1]}, one step "
                           f"before the windows {expected}); bpsflow reads hour-ending stamps, "
                           f"01:00 for the mean over 00:00-01:00, so add "
                           f"{shift} to them",
                           source=path)
    if not inside.any():
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}': no row falls in any test window (the "
                           f"file runs from {frame.index[0]} to {frame.index[-1]}; expected "
                           f"hour-ending stamps in {expected}, year {year} = model.year)",
                           source=path)
    notes.append(f"{path.name}: {int((~inside).sum())} of {len(frame)} rows lie outside every "
                 f"test window and were left out (kept {frame.index[inside][0]} .. "
                 f"{frame.index[inside][-1]})")
    return frame.loc[inside]


def _aggregate(frame: pd.DataFrame, config: Config, path: Path,
               notes: list[str]) -> tuple[pd.DataFrame, dict[str, str]]:
    """Sub-step data aggregated to each column's model resolution (hour- or step-ending)."""
    step = _file_step(frame.index, path)
    if step is None:
        return frame, {}
    pieces: list[pd.DataFrame] = []
    aggregation: dict[str, str] = {}
    rules: dict[tuple[pd.Timedelta, str], list[str]] = {}
    dropped: dict[str, list[pd.Timestamp]] = {}
    # the outputs the tests use are checked first: an error names a column that matters
    used = {output for test in config.model.tests for output in test.outputs}
    for column in sorted(frame.columns, key=lambda c: c not in used):
        if step != output_resolution(config, column):
            _check_step(step, output_resolution(config, column), column, path)
    for column in frame.columns:
        target = output_resolution(config, column)
        if step == target:
            pieces.append(frame[[column]])
            continue
        _check_step(step, target, column, path)
        unit = config.outputs[column].unit if column in config.outputs else ""
        rule = aggregation_rule(unit) if column in config.outputs else "mean"
        if rule is None:
            raise BpsflowError(f"column '{column}': {_minutes(step)} data must be aggregated to "
                               f"{_minutes(target)}, but its unit '{unit}' has no rule (mean "
                               f"for {', '.join(sorted(MEAN_UNITS))}; sum for "
                               f"{', '.join(sorted(SUM_UNITS))}); declare outputs.{column}.unit",
                               source=path)
        series, incomplete = _bin(frame[column], step, target, rule)
        pieces.append(series.to_frame())
        aggregation[column] = (f"{_minutes(step)} data {'averaged' if rule == 'mean' else 'summed'}"
                               f" to {_minutes(target)}")
        rules.setdefault((target, rule), []).append(unit or f"'{column}'")
        if incomplete:
            dropped[column] = incomplete
    if aggregation:
        targets: dict[pd.Timedelta, list[str]] = {}
        for (target, rule), units in rules.items():
            targets.setdefault(target, []).append(f"{rule} for {', '.join(dict.fromkeys(units))}")
        how = "; ".join(f"to {_minutes(target)}: " * (len(targets) > 1) + "; ".join(parts)
                        for target, parts in targets.items())
        into = _minutes(next(iter(targets))) if len(targets) == 1 else "the model's resolution"
        text = f"{path.name}: {_minutes(step)} data aggregated to {into} ({how}; hour-ending bins)"
        if dropped:
            text += ("; bins missing some of their sub-steps left out, not averaged from fewer "
                     "values: " + ", ".join(f"{column} {len(stamps)} (first {stamps[0]})"
                                            for column, stamps in dropped.items()))
        notes.append(text)
    return pd.concat(pieces, axis=1, sort=True), aggregation


def _file_step(index: pd.DatetimeIndex, path: Path) -> pd.Timedelta | None:
    """The file's time step (the most common spacing); errors for irregular stamps."""
    if len(index) < 2:
        return None
    gaps = pd.TimedeltaIndex(index[1:] - index[:-1])
    step = gaps.value_counts().index[0]
    irregular = np.flatnonzero(gaps % step != pd.Timedelta(0))
    if len(irregular):
        i = int(irregular[0]) + 1
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}': irregular time steps ({index[i - 1]} "
                           f"to {index[i]} is {_minutes(gaps[i - 1])}, the file's step is "
                           f"{_minutes(step)}); expected a constant step", source=path)
    off_grid = np.flatnonzero((index - index.floor("h")) % step != pd.Timedelta(0))
    if len(off_grid) and pd.Timedelta(hours=1) % step == pd.Timedelta(0):
        raise BpsflowError(f"column '{TIMESTAMP_COLUMN}': {index[off_grid[0]]} is not on the "
                           f"{_minutes(step)} grid of the hour; expected step-ending stamps "
                           f"(e.g. :15, :30, :45, :00)", source=path)
    return step


def _check_step(step: pd.Timedelta, target: pd.Timedelta, column: str, path: Path) -> None:
    """Error when ``step`` cannot be aggregated to ``target``."""
    if step > target:
        raise BpsflowError(f"column '{column}': the file's time step ({_minutes(step)}) is "
                           f"coarser than the model's resolution for it ({_minutes(target)}); "
                           f"expected {_minutes(target)} data or finer", source=path)
    if target % step != pd.Timedelta(0):
        raise BpsflowError(f"column '{column}': the file's time step ({_minutes(step)}) does "
                           f"not divide the model's resolution ({_minutes(target)}); expected "
                           f"e.g. 5-, 10-, 15- or 30-min data", source=path)


def _bin(series: pd.Series, step: pd.Timedelta, target: pd.Timedelta, rule: str
         ) -> tuple[pd.Series, list[pd.Timestamp]]:
    """Step-ending bins of ``target``: mean or sum of complete bins; incomplete ones left out.

    Returns the aggregated series (complete bins only) and the end stamps of
    the bins that had some but not all of their sub-steps.
    """
    per_bin = int(target / step)
    groups = series.groupby(series.index.ceil(target))
    count = groups.count()
    value = groups.mean() if rule == "mean" else groups.sum(min_count=1)
    complete = count == per_bin
    incomplete = list(count.index[(count > 0) & ~complete])
    return value[complete], incomplete


def _minutes(step: pd.Timedelta) -> str:
    minutes = step / pd.Timedelta(minutes=1)
    if minutes >= 60 and minutes % 60 == 0:
        return "hourly" if minutes == 60 else f"{minutes / 60:g}-hour"
    return f"{minutes:g}-min"
