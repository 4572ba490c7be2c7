"""Where a date's hours are in an hourly one-year file: the one hour-of-year rule.

Weather files (EPW), ``Schedule:File`` tables and the measured boundary
temperatures all hold one row per hour of a year, starting 1 January 00:00:
row ``r`` covers the hour ``r .. r + 1`` h after that. Their own year does not
matter (a TMY file mixes years); a date is found by its month, day and hour,
in the calendar the file's length implies:

* **8760 rows** — a non-leap year. In a leap ``model.year``, 29 February reads
  28 February's rows, and 1 March reads row ``59 * 24`` as in any other year.
  This is what EnergyPlus does: reading an 8760-hour ``Schedule:File`` it
  copies 28 February's day to 29 February (ScheduleManager), and it never
  makes up a 29 February that a weather file does not have.
* **8784 rows** — a leap year. 29 February has its own rows, and a date after
  February in a non-leap ``model.year`` skips them (1 March is row
  ``60 * 24``): EnergyPlus indexes its schedule days on a 366-day calendar.

Counting hours from 1 January of ``model.year`` instead (``tm_yday``,
``Timestamp.day_of_year``) is wrong in a leap year: every row after February
would be 24 rows late in an 8760-row file.
"""

from __future__ import annotations

from datetime import date

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError

#: Rows of an hourly file of a non-leap and of a leap year.
NON_LEAP_ROWS = 8760
LEAP_ROWS = 8784

# 0-based day of the year on which each month starts, per file calendar.
_MONTH_START = {
    NON_LEAP_ROWS: np.cumsum([0, 31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30]),
    LEAP_ROWS: np.cumsum([0, 31, 29, 31, 30, 31, 30, 31, 31, 30, 31, 30]),
}


def hour_rows(hour_starts: pd.DatetimeIndex | pd.Series | np.ndarray,
              n_rows: int = NON_LEAP_ROWS) -> np.ndarray:
    """0-based row of the hour that contains each timestamp, in an ``n_rows`` file.

    Parameters
    ----------
    hour_starts : DatetimeIndex, Series of datetime64 or array of datetime64
        Local (standard) time of each hour's start; a timestamp inside an
        hour gives that hour's row. An hour-ending stamp ``t`` (the usual
        label of measured and simulated hourly values) covers
        ``t - 1 h .. t``: pass ``t - 1 h``.
    n_rows : {8760, 8784}
        Rows of the file: 8760 for a non-leap (e.g. TMY) year, 8784 for a
        leap year. See the module docstring for how 29 February maps.

    Returns
    -------
    ndarray of int
        Rows in ``0 .. n_rows - 1``, one per timestamp.

    Raises
    ------
    BpsflowError
        ``n_rows`` is neither 8760 nor 8784.
    """
    month_starts = _month_starts(n_rows)
    starts = pd.DatetimeIndex(hour_starts)
    month = starts.month.to_numpy()
    day = starts.day.to_numpy()
    if n_rows == NON_LEAP_ROWS:
        # the file has no 29 February: that day reads 28 February's rows
        day = np.where((month == 2) & (day == 29), 28, day)
    day_of_file = month_starts[month - 1] + day - 1
    return (day_of_file * 24 + starts.hour.to_numpy()).astype(int)


def day_row(day: date | pd.Timestamp, n_rows: int = NON_LEAP_ROWS) -> int:
    """0-based row of the first hour (00:00-01:00) of ``day`` in an ``n_rows`` file.

    Parameters
    ----------
    day : date or Timestamp
        The calendar day (of ``model.year``; only its month and day count).
    n_rows : {8760, 8784}
        Rows of the file, as in :func:`hour_rows`.

    Returns
    -------
    int
    """
    return int(hour_rows(pd.DatetimeIndex([pd.Timestamp(day.year, day.month, day.day)]),
                         n_rows)[0])


def day_rows(first: date | pd.Timestamp, days: int, n_rows: int = NON_LEAP_ROWS) -> np.ndarray:
    """0-based row of the first hour of each of ``days`` consecutive days from ``first``.

    The rows of consecutive days are 24 apart except across the end of
    February when the file's calendar and the days' differ (a repeated or a
    skipped day), which is why a period's rows are not ``row0 + arange``.

    Parameters
    ----------
    first : date or Timestamp
        The first day.
    days : int
        Number of days.
    n_rows : {8760, 8784}
        Rows of the file, as in :func:`hour_rows`.

    Returns
    -------
    ndarray of int, shape (days,)
    """
    start = pd.Timestamp(first.year, first.month, first.day)
    return hour_rows(pd.date_range(start, periods=days, freq="D"), n_rows)


def row_starts(year: int, n_rows: int = NON_LEAP_ROWS) -> pd.DatetimeIndex:
    """The hour of ``year`` that each row of an ``n_rows`` file is read for: the inverse rule.

    For writing a file a simulation of ``year`` reads (e.g. a ``Schedule:File``
    profile): evaluate the profile at these hour starts, one per row.

    Parameters
    ----------
    year : int
        The simulated year (``model.year``).
    n_rows : {8760, 8784}
        Rows of the file to write.

    Returns
    -------
    DatetimeIndex, length ``n_rows``
        Start of the hour each row is read for. In a leap ``year`` with 8760
        rows, 29 February has no row (it reads 28 February's); in a non-leap
        ``year`` with 8784 rows, the 29 February rows are read for no hour
        (``NaT``).
    """
    _month_starts(n_rows)
    hours = pd.date_range(pd.Timestamp(year, 1, 1), pd.Timestamp(year + 1, 1, 1), freq="h",
                          inclusive="left")
    if n_rows == NON_LEAP_ROWS:
        hours = hours[~((hours.month == 2) & (hours.day == 29))]
    out = pd.Series(pd.NaT, index=np.arange(n_rows), dtype="datetime64[ns]")
    out.iloc[hour_rows(hours, n_rows)] = hours
    return pd.DatetimeIndex(out.to_numpy())


def _month_starts(n_rows: int) -> np.ndarray:
    try:
        return _MONTH_START[int(n_rows)]
    except KeyError:
        raise BpsflowError(f"an hourly year file has 8760 (non-leap) or 8784 (leap) rows, "
                           f"not {n_rows}") from None
