"""Boundary-temperature sequences for surfaces next to measured spaces (seed §3.4.5).

The measured (area-weighted, eq. 13) temperature of each boundary surface has
a random error of standard deviation ``sensor_std_c`` (the surface's own value
when it has one, e.g. from ``bpsflow refine``; else the boundary-level value).
A Monte Carlo set of
``sequences`` sequences per surface is drawn *independently at each time step*
with a Latin hypercube (stratified over the sequences), and a U(0,1) sampler
per surface selects the sequence one instance uses. The sequences cover the
run periods only (the model never reads other hours); elsewhere the measured
values stand.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Boundary, Config, period_dates
from bpsflow.errors import BpsflowError
from bpsflow.files import write_npz, write_text_atomic
from bpsflow.tables import read_table
from bpsflow.yearhours import NON_LEAP_ROWS, day_rows

SEQUENCES_FILE = "boundary_sequences.npz"
#: Temperatures (°C) a boundary surface beside a conditioned room can take; outside them the
#: file is in another unit (kelvin, °F) or another sensor's.
BOUNDARY_RANGE_C = (-30.0, 60.0)


@lru_cache(maxsize=4)
def read_boundary_file(path: Path, columns: tuple[str, ...]) -> pd.DataFrame:
    """Read the measured boundary temperatures (one row per hour of the year, °C)."""
    frame = read_table(path, columns, "boundary temperature",
                       where="model.boundary.surfaces.*.column", numeric_columns=columns)
    if len(frame) not in (8760, 8784):
        raise BpsflowError(f"expected one row per hour of a year (8760), found {len(frame)}",
                           source=path)
    stamp_column = next((c for c in frame.columns if str(c).strip().lower() in STAMP_COLUMNS),
                        None)
    if stamp_column is not None:
        check_hour_order(frame[stamp_column].astype(str).tolist(), path, stamp_column)
    values = frame[list(columns)]
    if not np.isfinite(values.to_numpy(dtype=float)).all():
        bad = int(np.argwhere(~np.isfinite(values.to_numpy(dtype=float)))[0][0])
        raise BpsflowError(f"row {bad + 2} holds a missing or non-numeric temperature", source=path)
    low, high = BOUNDARY_RANGE_C
    for column in columns:
        numbers = values[column].to_numpy(dtype=float)
        outside = (numbers < low) | (numbers > high)
        if outside.any():
            row = int(np.flatnonzero(outside)[0])
            hint = ("; kelvin in a °C column?" if low <= numbers[row] - 273.15 <= high else
                    "; °F in a °C column?" if low <= (numbers[row] - 32) / 1.8 <= high else "")
            raise BpsflowError(f"column '{column}', row {row + 2}: {numbers[row]:g} is outside "
                               f"the {low:g}..{high:g} °C a surface beside a room takes "
                               f"({int(outside.sum())} value(s) outside){hint}", source=path)
    return frame


#: Column names read as the boundary file's timestamps (no case).
STAMP_COLUMNS = ("timestamp", "time", "date/time", "datetime", "date")

_MONTH_DAY = re.compile(r"\s*(\d{1,2})/(\d{1,2})\s+(\d{1,2}):(\d{2})(?::\d{2})?\s*$")
_ISO = re.compile(r"\s*(\d{4})-(\d{2})-(\d{2})[ T](\d{2}):(\d{2})(?::\d{2})?\s*$")


def check_hour_order(stamps: list[str], path: Path, column: str) -> None:
    """Refuse a boundary file whose timestamps are not the year's hours in order.

    EnergyPlus's Schedule:File, and the sequences drawn from the file, read it
    by row: row *k* is the hour ending at *k* + 1 hours after 1 January
    00:00. A timestamp column is therefore checked, not trusted: sorted
    otherwise, hour-beginning or shifted stamps would put every value at
    another hour without a word. ``MM/DD HH:MM`` (EnergyPlus's, 24:00 ends a
    day) and ISO ``YYYY-MM-DD HH:MM`` stamps are read; the year is ignored.

    Raises
    ------
    BpsflowError
        Naming the file, the column and the first row that is not the
        expected hour (with the hour it should be).
    """
    leap = len(stamps) == 8784
    month_starts = np.cumsum([0, 31, 29 if leap else 28, 31, 30, 31, 30, 31, 31, 30, 31, 30])
    first_year = None
    for row, text in enumerate(stamps):
        iso = _ISO.match(text)
        found = iso or _MONTH_DAY.match(text)
        if found is None:
            raise BpsflowError(f"column '{column}', row {row + 2}: '{text}' is not a timestamp "
                               f"(expected MM/DD HH:MM, hour-ending, e.g. '{_hour_text(row, leap)}')",
                               source=path)
        numbers = [int(g) for g in found.groups()]
        year = numbers.pop(0) if iso else None
        month, day, hour, minute = numbers
        if not (1 <= month <= 12 and 1 <= day <= 31 and hour <= 24 and minute < 60):
            raise BpsflowError(f"column '{column}', row {row + 2}: '{text}' is not a valid "
                               f"date and time (expected '{_hour_text(row, leap)}')", source=path)
        first_year = year if first_year is None else first_year
        # an ISO stamp may end the year at the next one's 01-01 00:00
        later_year = 0 if year is None or first_year is None else year - first_year
        hours = (later_year * (366 if leap else 365) + int(month_starts[month - 1]) + day - 1) \
            * 24 + hour + minute / 60
        if hours != row + 1:
            problem = ("the stamps begin their hours (00:00..23:00): expected hour-ending "
                       "stamps (01:00..24:00)" if hours == row else
                       "the rows are not the year's hours in order")
            raise BpsflowError(f"column '{column}', row {row + 2}: '{text}', expected "
                               f"'{_hour_text(row, leap)}': "
                               f"{problem}; the file is read by row (row k is the hour ending "
                               f"k h after 1 January 00:00), so each row must be its hour",
                               source=path)


def _hour_text(row: int, leap: bool) -> str:
    """Row ``row``'s hour-ending stamp as EnergyPlus writes it (``MM/DD HH:MM``, 24:00)."""
    expected = pd.Timestamp(2024 if leap else 2025, 1, 1) + pd.Timedelta(hours=row + 1)
    return f"{expected:%m/%d %H:%M}" if expected.hour else \
        f"{expected - pd.Timedelta(days=1):%m/%d} 24:00"


def period_hours(config: Config, n_rows: int | None = None) -> np.ndarray:
    """0-based rows, in an hourly one-year file, of the hours of the config's run periods.

    Parameters
    ----------
    config : Config
    n_rows : {8760, 8784}, optional
        Rows of the file the result indexes (:mod:`bpsflow.yearhours`: in a
        leap ``model.year`` an 8760-row file has no 29 February). Default:
        the measured boundary file's, whose rows the boundary sequences
        hold, or 8760 without one; a caller indexing another file (the EPW)
        passes that file's length.

    Returns
    -------
    ndarray of int
        Sorted, unique rows.
    """
    if n_rows is None:
        n_rows = NON_LEAP_ROWS if config.model.boundary is None else \
            boundary_rows(config.model.boundary)
    hours: list[np.ndarray] = []
    for period in config.model.periods:
        first, last = period_dates(period, config.model.year)
        starts = day_rows(first, (last - first).days + 1, n_rows)
        hours.append((starts[:, None] + np.arange(24)[None, :]).ravel())
    return np.unique(np.concatenate(hours))


def boundary_rows(boundary: Boundary) -> int:
    """Rows (8760 or 8784) of the measured boundary temperature file."""
    columns = tuple(boundary.surfaces[s].column for s in boundary.surfaces)
    return len(read_boundary_file(boundary.file, columns))


@dataclass(frozen=True)
class BoundarySequences:
    """``values[surface][sequence, k]`` is the temperature (°C) at hour row ``hours[k]``."""

    surfaces: tuple[str, ...]
    hours: np.ndarray
    values: np.ndarray  # (n_surfaces, n_sequences, n_hours), float32

    def sequence(self, surface: str, index: int) -> np.ndarray:
        return self.values[self.surfaces.index(surface), int(index)]


def surface_std_c(boundary: Boundary, surface: str) -> float:
    """Measurement standard deviation (°C) of one boundary surface's temperature."""
    own = boundary.surfaces[surface].sensor_std_c
    return boundary.sensor_std_c if own is None else own


def draw_sequences(boundary: Boundary, hours: np.ndarray) -> BoundarySequences:
    """Draw the Monte Carlo boundary sequences (LHS over sequences at each time step).

    For surface ``s`` and hour ``t`` the ``N`` values are
    ``T_meas(t) + sigma_s * Phi^-1((pi_t(j) + U_j) / N)``, ``pi_t`` a random
    permutation: an independent Latin hypercube per time step (seed §3.4.5).
    ``sigma_s`` (°C) is the surface's ``sensor_std_c`` if set, else the
    boundary's.
    """
    from scipy.special import ndtri

    surfaces = tuple(boundary.surfaces)
    columns = tuple(boundary.surfaces[s].column for s in surfaces)
    measured = read_boundary_file(boundary.file, columns)[list(columns)].to_numpy(dtype=float)[hours]
    rng = np.random.default_rng(boundary.seed)
    n = boundary.sequences
    strata = rng.permuted(np.broadcast_to(np.arange(n)[:, None], (n, len(hours))), axis=0)
    values = np.empty((len(surfaces), n, len(hours)), dtype=np.float32)
    for s, surface in enumerate(surfaces):
        u = (rng.permuted(strata, axis=0) + rng.random((n, len(hours)))) / n
        values[s] = measured[:, s][None, :] + surface_std_c(boundary, surface) * ndtri(u)
    return BoundarySequences(surfaces=surfaces, hours=hours, values=values)


def ensure_sequences(config: Config) -> Path | None:
    """Draw and write the run directory's boundary sequences unless they are there already."""
    if config.model.boundary is None:
        return None
    path = config.run_dir.resolve() / SEQUENCES_FILE
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_sequences(draw_sequences(config.model.boundary, period_hours(config)), path.parent)
    return path


def write_sequences(sequences: BoundarySequences, run_dir: Path) -> Path:
    path = run_dir / SEQUENCES_FILE
    write_npz(path, surfaces=np.array(sequences.surfaces), hours=sequences.hours,
              values=sequences.values)
    return path


def read_sequences(path: Path) -> BoundarySequences:
    """The boundary sequences in ``path`` (cached while the file is unchanged)."""
    if not path.is_file():
        raise BpsflowError(f"boundary sequences not found: {path}; run 'bpsflow sample' first")
    stat = path.stat()
    # keyed by the file's identity too: a new design rewrites the file under the same name
    return _read_sequences(path, stat.st_ino, stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=2)
def _read_sequences(path: Path, inode: int, mtime_ns: int, size: int) -> BoundarySequences:
    try:
        with np.load(path) as data:
            return BoundarySequences(surfaces=tuple(str(s) for s in data["surfaces"]),
                                     hours=data["hours"], values=data["values"])
    except (OSError, ValueError, KeyError, EOFError) as exc:
        # a damaged file would otherwise fail every instance with numpy's own words
        raise BpsflowError(f"{path}: not a readable boundary-sequence file ({exc}); it was "
                           "damaged after bpsflow wrote it: delete it and run 'bpsflow sample' "
                           "with --force to draw the design again") from None


@lru_cache(maxsize=4)
def _boundary_lines(path: Path, columns: tuple[str, ...]) -> tuple[str, tuple[str, ...]]:
    table = read_boundary_file(path, columns)
    header = ",".join(table.columns)
    lines = table.to_csv(index=False, header=False, float_format="%.3f").splitlines()
    return header, tuple(lines)


def write_boundary_file(boundary: Boundary, sequences: BoundarySequences | None,
                        selection: dict[str, int], path: Path) -> Path:
    """Write the instance's boundary file: measured data with the selected sequences substituted.

    Same layout as the measured file (so the model's Schedule:File column
    numbers hold); only the rows of the sequences' hours are re-rendered.
    """
    columns = tuple(boundary.surfaces[s].column for s in boundary.surfaces)
    table = read_boundary_file(boundary.file, columns)
    header, base_lines = _boundary_lines(boundary.file, columns)
    lines = list(base_lines)
    if selection:
        hours = sequences.hours.tolist()
        # each column formatted at once (a list of its texts), then the rows joined
        texts = []
        for name in table.columns:
            surface = next((s for s in selection if boundary.surfaces[s].column == name), None)
            column = (sequences.sequence(surface, selection[surface]) if surface is not None
                      else table[name].to_numpy()[hours])
            texts.append([v if isinstance(v, str) else f"{v:.4f}" for v in column.tolist()])
        for hour, fields in zip(hours, zip(*texts)):
            lines[hour] = ",".join(fields)
    return write_text_atomic(path, header + "\n" + "\n".join(lines) + "\n")
