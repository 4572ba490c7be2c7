"""EPW weather files: parsing with clear errors, and instance files with sensor errors.

Seed §3.4.4: with an on-site weather station, sensor error (Table 3.2) is the
only uncertainty in the meteorological conditions; each instance gets its own
weather file with sampled errors on dry bulb and dew point temperature,
global and diffuse irradiance, wind speed and direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError
from bpsflow.files import write_text_atomic
from bpsflow.yearhours import hour_rows

#: 0-based column of each quantity in an EPW data row (EnergyPlus Auxiliary Programs, ch. 2).
EPW_COLUMNS = {
    "dry_bulb_temperature": 6,           # °C
    "dew_point_temperature": 7,          # °C
    "relative_humidity": 8,              # %
    "atmospheric_pressure": 9,           # Pa
    "global_horizontal_radiation": 13,   # Wh/m² (hourly mean W/m²)
    "direct_normal_radiation": 14,       # Wh/m²
    "diffuse_horizontal_radiation": 15,  # Wh/m²
    "wind_direction": 20,                # degrees from north
    "wind_speed": 21,                    # m/s
}
_HEADER_LINES = 8
#: The EPW header, one keyword per line, in order (EnergyPlus Auxiliary Programs, ch. 2).
HEADER_KEYWORDS = ("LOCATION", "DESIGN CONDITIONS", "TYPICAL/EXTREME PERIODS",
                   "GROUND TEMPERATURES", "HOLIDAYS/DAYLIGHT SAVINGS", "COMMENTS 1",
                   "COMMENTS 2", "DATA PERIODS")
#: Fields of an EPW data row.
DATA_FIELDS = 35
#: Data fields that must be numbers: the date and time, then every meteorological field
#: up to wind speed (what EnergyPlus reads for the heat balance; the tail, e.g. present
#: weather codes and snow depth, is left to EnergyPlus).
_NUMERIC_FIELDS = (0, 1, 2, 3, 4, *range(6, 22))
#: The fields the tool and EnergyPlus use: (the EPW data dictionary's valid range, the
#: EPW's missing-value marker, unit). A marker is refused: EnergyPlus would carry the
#: previous hour forward, and a sensor error added to a marker is no value at all.
#: Irradiance has no upper bound in the dictionary; above the solar constant
#: (1361 W/m²) plus a margin it is a unit or format mistake.
EPW_RANGES: dict[str, tuple[float, float, float, str]] = {
    "dry_bulb_temperature": (-70.0, 70.0, 99.9, "°C"),
    "dew_point_temperature": (-70.0, 70.0, 99.9, "°C"),
    "relative_humidity": (0.0, 110.0, 999.0, "%"),
    "atmospheric_pressure": (31000.0, 120000.0, 999999.0, "Pa"),
    "global_horizontal_radiation": (0.0, 1500.0, 9999.0, "Wh/m²"),
    "direct_normal_radiation": (0.0, 1500.0, 9999.0, "Wh/m²"),
    "diffuse_horizontal_radiation": (0.0, 1500.0, 9999.0, "Wh/m²"),
    "wind_direction": (0.0, 360.0, 999.0, "degrees"),
    "wind_speed": (0.0, 40.0, 999.0, "m/s"),
}
#: LOCATION fields (0-based, after the keyword at 0) that are numbers, with their ranges.
_LOCATION_NUMBERS = {6: ("latitude", -90.0, 90.0), 7: ("longitude", -180.0, 180.0),
                     8: ("time zone", -12.0, 14.0), 9: ("elevation", -1000.0, 9999.9)}


@dataclass(frozen=True)
class EpwFile:
    """A parsed EPW: the 8 header lines, the raw data rows and the numeric columns we touch."""

    path: Path
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    columns: dict[str, np.ndarray]

    @property
    def n_hours(self) -> int:
        return len(self.rows)


def read_epw(path: Path) -> EpwFile:
    """Parse and check an EPW file, raising a clear error naming the line and field.

    The whole file is checked, as EnergyPlus would read it: the 8 header lines
    (LOCATION with numeric latitude, longitude, time zone and elevation), 8760
    or 8784 data rows of 35 fields, the month/day/hour sequence of a whole
    year (no hour out of order or repeated), numbers where EnergyPlus reads
    numbers, and each field the tool uses within the EPW data dictionary's
    range (:data:`EPW_RANGES`; missing-value markers refused). The parse is
    cached per process and file version: every instance written by a worker
    starts from the same parse.

    Raises
    ------
    BpsflowError
        With the file as source and the line number and field of the first problem.
    """
    path = Path(path)
    try:
        stat = path.stat()
    except OSError as exc:
        raise BpsflowError(f"cannot read the weather file: {exc.strerror or exc}",
                           source=path) from None
    return _read_epw(path, stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=4)
def _read_epw(path: Path, mtime_ns: int, size: int) -> EpwFile:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BpsflowError(f"cannot read the weather file: {exc.strerror or exc}",
                           source=path) from None
    if not data.strip():
        raise BpsflowError("the weather file is empty; expected an EPW file (8 header lines "
                           "starting with LOCATION, then 8760 or 8784 hourly rows)", source=path)
    text = _text(data)
    if text is None:
        raise BpsflowError("not an EPW weather file: binary content, not text", source=path)
    lines = text.splitlines()
    header = tuple(lines[:_HEADER_LINES])
    _check_header(header, path)
    rows = tuple(tuple(line.split(",")) for line in lines[_HEADER_LINES:] if line.strip())
    if len(rows) not in (8760, 8784):
        raise BpsflowError(f"expected 8760 or 8784 hourly data rows after the 8 header lines, "
                           f"found {len(rows)} (a truncated file, or not hourly data)",
                           source=path)
    first_line = {i: n + 1 for i, n in enumerate(
        k for k, line in enumerate(lines) if k >= _HEADER_LINES and line.strip())}
    for i, row in enumerate(rows):
        if len(row) != DATA_FIELDS:
            raise BpsflowError(f"line {first_line[i]}: {len(row)} comma-separated fields, "
                               f"expected the EPW's {DATA_FIELDS}", source=path)
    numbers = _numeric_fields(rows, path, first_line)
    _check_sequence(numbers, path, first_line)
    columns: dict[str, np.ndarray] = {}
    for name, column in EPW_COLUMNS.items():
        values = numbers[:, _NUMERIC_FIELDS.index(column)]
        low, high, missing, unit = EPW_RANGES[name]
        bad = (values < low) | (values > high) | (values == missing)
        if bad.any():
            i = int(np.argmax(bad))
            what = ("the EPW missing-value marker; fill the gap (EnergyPlus would repeat the "
                    "previous hour)" if values[i] == missing else
                    f"outside the EPW range {low:g}..{high:g} {unit}")
            raise BpsflowError(f"line {first_line[i]}, field {column + 1} ({name}): "
                               f"{values[i]:g} is {what}", source=path)
        columns[name] = values
    return EpwFile(path=path, header=header, rows=rows, columns=columns)


def _text(data: bytes) -> str | None:
    """The file's text (UTF-8, else Latin-1 as some converters write), or None for binary data."""
    if b"\x00" in data:
        return None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    controls = sum(not (c.isprintable() or c in "\r\n\t") for c in text[:4096])
    return None if controls > 8 else text


def _check_header(header: tuple[str, ...], path: Path) -> None:
    """The 8 header lines in order, and a LOCATION line EnergyPlus can read."""
    for i, keyword in enumerate(HEADER_KEYWORDS):
        if i >= len(header) or header[i].split(",", 1)[0].strip().upper() != keyword:
            raise BpsflowError(
                f"line {i + 1}: expected the EPW header line '{keyword},...' (an EPW starts "
                f"with {len(HEADER_KEYWORDS)} header lines: {', '.join(HEADER_KEYWORDS)}); "
                f"not an EPW weather file", source=path)
    location = header[0].split(",")
    if len(location) < 10:
        raise BpsflowError(f"line 1: LOCATION has {len(location) - 1} fields, expected 9 (city, "
                           f"state, country, source, WMO, latitude, longitude, time zone, "
                           f"elevation)", source=path)
    for index, (name, low, high) in _LOCATION_NUMBERS.items():
        text = location[index].strip()
        if not _is_number(text) or not low <= float(text) <= high:
            raise BpsflowError(f"line 1, LOCATION field {index + 1} ({name}): expected a number "
                               f"in {low:g}..{high:g}", source=path)


def _numeric_fields(rows, path: Path, first_line: dict[int, int]) -> np.ndarray:
    """The numeric fields of every row (:data:`_NUMERIC_FIELDS`), as an array."""
    try:
        return np.array([[float(row[k]) for k in _NUMERIC_FIELDS] for row in rows])
    except ValueError:
        for i, row in enumerate(rows):
            for k in _NUMERIC_FIELDS:
                if not _is_number(row[k]):
                    raise BpsflowError(f"line {first_line[i]}, field {k + 1}: not a number "
                                       f"(EnergyPlus reads a number there)", source=path) from None
        raise


def _check_sequence(numbers: np.ndarray, path: Path, first_line: dict[int, int]) -> None:
    """Month, day and hour run through one whole year, one row per hour, in order."""
    n = len(numbers)
    stamps = pd.date_range("2024-01-01" if n == 8784 else "2023-01-01", periods=n, freq="h")
    expected = np.column_stack([stamps.month, stamps.day, stamps.hour + 1])
    found = numbers[:, 1:4]
    bad = np.any(found != expected, axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        month, day, hour = (int(v) if float(v).is_integer() else v for v in found[i])
        raise BpsflowError(
            f"line {first_line[i]}: month/day/hour {month}/{day}/{hour}, expected "
            f"{expected[i][0]}/{expected[i][1]}/{expected[i][2]} (an EPW has one row per hour of "
            f"a {'leap ' if n == 8784 else ''}year, in order; an hour out of order, repeated "
            f"or missing)", source=path)


def epw_rows(hour_starts: pd.DatetimeIndex | pd.Series, n_rows: int = 8760) -> np.ndarray:
    """0-based EPW data row of each hour, mapped by month, day and hour.

    The rule of :func:`bpsflow.yearhours.hour_rows` (the EPW's own year is
    ignored; an 8760-row file reads 28 February for 29 February, an 8784-row
    file skips 29 February in a non-leap year).

    Parameters
    ----------
    hour_starts : DatetimeIndex or Series of datetime64
        Start of each hour, local standard time (an hour-ending timestamp
        ``t`` covers ``t - 1 h .. t``: pass ``t - 1 h``).
    n_rows : int
        Data rows of the EPW, 8760 or 8784.

    Returns
    -------
    ndarray of int
    """
    return hour_rows(hour_starts, n_rows)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _relative_humidity_pct(dry_bulb_c: np.ndarray, dew_point_c: np.ndarray) -> np.ndarray:
    """RH from dry bulb and dew point (Magnus formula over water), in %."""
    a, b = 17.625, 243.04
    ratio = np.exp(a * dew_point_c / (b + dew_point_c) - a * dry_bulb_c / (b + dry_bulb_c))
    return np.clip(100.0 * ratio, 0.0, 100.0)


def perturb(epw: EpwFile, errors: dict[str, tuple[str, float]]) -> dict[str, np.ndarray]:
    """Apply sensor errors to the weather columns, keeping the file self-consistent.

    Parameters
    ----------
    epw : EpwFile
    errors : dict
        ``{quantity: (mode, value)}``, mode ``additive`` (e.g. a dry-bulb bias
        in °C), ``relative`` (e.g. a global irradiance gain) or ``absolute``.

    Returns
    -------
    dict
        The changed columns. When global or diffuse irradiance change and
        direct normal is not itself perturbed, direct normal is rescaled so the
        beam part ``GHI - DHI`` stays consistent (EnergyPlus uses DNI and DHI);
        the dew point is kept at or below the dry bulb and RH recomputed.
    """
    new = {name: epw.columns[name].copy() for name in errors}
    for name, (mode, value) in errors.items():
        base = epw.columns[name]
        new[name] = base * value if mode == "relative" else base + value if mode == "additive" \
            else np.full_like(base, value)
    if "wind_speed" in new:
        new["wind_speed"] = np.clip(new["wind_speed"], 0.0, None)
    if "wind_direction" in new:
        new["wind_direction"] = np.mod(new["wind_direction"], 360.0)
    for name in ("global_horizontal_radiation", "diffuse_horizontal_radiation",
                 "direct_normal_radiation"):
        if name in new:
            new[name] = np.clip(new[name], 0.0, None)
    irradiance_changed = {"global_horizontal_radiation", "diffuse_horizontal_radiation"} & set(new)
    if irradiance_changed and "direct_normal_radiation" not in new:
        ghi = new.get("global_horizontal_radiation", epw.columns["global_horizontal_radiation"])
        dhi = new.get("diffuse_horizontal_radiation", epw.columns["diffuse_horizontal_radiation"])
        dhi = np.minimum(dhi, ghi)
        old_beam = epw.columns["global_horizontal_radiation"] - epw.columns["diffuse_horizontal_radiation"]
        ratio = np.divide(ghi - dhi, old_beam, out=np.ones_like(ghi), where=old_beam > 1.0)
        new["direct_normal_radiation"] = np.clip(epw.columns["direct_normal_radiation"] * ratio, 0, None)
        new["diffuse_horizontal_radiation"] = dhi
    if {"dry_bulb_temperature", "dew_point_temperature"} & set(new):
        dry = new.get("dry_bulb_temperature", epw.columns["dry_bulb_temperature"])
        dew = np.minimum(new.get("dew_point_temperature", epw.columns["dew_point_temperature"]), dry)
        new["dew_point_temperature"] = dew
        new["relative_humidity"] = _relative_humidity_pct(dry, dew)
    return new


_FORMATS = {"relative_humidity": "{:.0f}", "wind_direction": "{:.0f}"}


@lru_cache(maxsize=4)
def _lines(path: Path) -> tuple[str, ...]:
    return tuple(",".join(row) for row in read_epw(path).rows)


@lru_cache(maxsize=8)
def _segments(path: Path, columns: tuple[int, ...]) -> tuple[tuple[str, ...], ...]:
    """Per data row, the constant text around ``columns`` (sorted): ``len(columns) + 1`` pieces.

    An instance then formats only the changed values and joins them with the
    pieces: the row is never split and rebuilt field by field.
    """
    pieces = []
    for row in read_epw(path).rows:
        bounds = (-1, *columns, len(row))
        # an empty field at either end of the join puts the comma next to a changed value
        row_pieces = [",".join(([""] if start >= 0 else []) + list(row[start + 1:end])
                               + ([""] if end < len(row) else []))
                      for start, end in zip(bounds[:-1], bounds[1:])]
        pieces.append(tuple(row_pieces))
    return tuple(pieces)


def write_epw(epw: EpwFile, changed: dict[str, np.ndarray], path: Path,
              rows: np.ndarray | None = None) -> Path:
    """Write ``epw`` with ``changed`` columns replaced to ``path``.

    ``rows`` (0-based data rows) limits the rewrite to the hours a simulation
    reads, the run periods; the other rows keep the measured values. This is
    the same simulation at a tenth of the writing cost.
    """
    rows = np.arange(epw.n_hours) if rows is None else np.asarray(rows)
    lines = list(_lines(epw.path))
    if changed:
        names = sorted(changed, key=lambda name: EPW_COLUMNS[name])
        segments = _segments(epw.path, tuple(EPW_COLUMNS[name] for name in names))
        row_list = rows.tolist()
        formatted = [[_FORMATS.get(name, "{:.1f}").format(v) for v in changed[name][row_list].tolist()]
                     for name in names]
        for k, i in enumerate(row_list):
            pieces = segments[i]
            parts = [pieces[0]]
            for column, values in enumerate(formatted):
                parts += [values[k], pieces[column + 1]]
            lines[i] = "".join(parts)
    return write_text_atomic(path, "\n".join(epw.header) + "\n" + "\n".join(lines) + "\n")
