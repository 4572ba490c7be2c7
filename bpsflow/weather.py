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


@lru_cache(maxsize=4)
def read_epw(path: Path) -> EpwFile:
    """Parse an EPW file, raising a clear error when it is not one.

    The parsed file is cached per process: every instance written by a worker
    starts from the same parse.
    """
    path = Path(path)
    try:
        lines = path.read_text(errors="strict").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise BpsflowError(f"cannot read the weather file: {exc}", source=path) from None
    if len(lines) < _HEADER_LINES + 1 or not lines[0].startswith("LOCATION"):
        raise BpsflowError("not an EPW weather file: expected 8 header lines starting with "
                           "'LOCATION' followed by hourly data rows", source=path)
    header = tuple(lines[:_HEADER_LINES])
    rows = tuple(tuple(line.split(",")) for line in lines[_HEADER_LINES:] if line.strip())
    if len(rows) not in (8760, 8784):
        raise BpsflowError(f"expected 8760 or 8784 hourly data rows, found {len(rows)}", source=path)
    columns: dict[str, np.ndarray] = {}
    for name, column in EPW_COLUMNS.items():
        try:
            columns[name] = np.array([float(row[column]) for row in rows])
        except (IndexError, ValueError):
            bad = next(i for i, row in enumerate(rows)
                       if len(row) <= column or not _is_number(row[column]))
            raise BpsflowError(
                f"data row {bad + 1} (line {bad + 1 + _HEADER_LINES}): field {column + 1} "
                f"({name}) is missing or not a number", source=path) from None
    return EpwFile(path=path, header=header, rows=rows, columns=columns)


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


def write_epw(epw: EpwFile, changed: dict[str, np.ndarray], path: Path,
              rows: np.ndarray | None = None) -> Path:
    """Write ``epw`` with ``changed`` columns replaced to ``path``.

    ``rows`` (0-based data rows) limits the rewrite to the hours a simulation
    reads, the run periods; the other rows keep the measured values. This is
    the same simulation at a tenth of the writing cost.
    """
    rows = np.arange(epw.n_hours) if rows is None else np.asarray(rows)
    lines = list(_lines(epw.path))
    formats = {EPW_COLUMNS[name]: _FORMATS.get(name, "{:.1f}") for name in changed}
    for i in rows.tolist():
        row = list(epw.rows[i])
        for name, values in changed.items():
            column = EPW_COLUMNS[name]
            row[column] = formats[column].format(values[i])
        lines[i] = ",".join(row)
    return write_text_atomic(path, "\n".join(epw.header) + "\n" + "\n".join(lines) + "\n")
