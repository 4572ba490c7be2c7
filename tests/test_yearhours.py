"""One hour-of-year rule (bpsflow.yearhours) for weather, boundary and schedule files.

Leap years included: an 8760-row file has no 29 February, an 8784-row file has one.
"""

from __future__ import annotations

from datetime import date, timedelta

import numpy as np
import pandas as pd
import pytest

from bpsflow.boundary import draw_sequences, period_hours, write_sequences
from bpsflow.config import load_config, period_dates
from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import read_idf
from bpsflow.surrogate.cell import build_cell
from bpsflow.surrogate.forcing import period_forcing
from bpsflow.surrogate.params import field_values, sample_columns
from bpsflow.surrogate.schedules import Schedule
from bpsflow.weather import epw_rows, read_epw
from bpsflow.yearhours import day_row, day_rows, hour_rows, row_starts

from conftest import short_raw, write_config


def _hours(first: str, last: str) -> pd.DatetimeIndex:
    return pd.date_range(first, last, freq="h")


def test_non_leap_year_is_the_plain_hour_count():
    hours = _hours("2025-01-01 00:00", "2025-12-31 23:00")
    # what every copy of the rule computed in a non-leap year: hours since 1 January
    np.testing.assert_array_equal(hour_rows(hours), np.arange(8760))
    for day in pd.date_range("2025-01-01", "2025-12-31").date:
        assert day_row(day) == (day.timetuple().tm_yday - 1) * 24
    # an 8784-row file in a non-leap year skips 29 February
    assert hour_rows(_hours("2025-03-01", "2025-03-01"), 8784)[0] == 60 * 24
    assert hour_rows(_hours("2025-02-28 23:00", "2025-02-28 23:00"), 8784)[0] == 59 * 24 - 1


def test_leap_year_in_an_8760_row_file_reads_28_february_for_29_february():
    assert day_row(date(2024, 3, 1)) == 59 * 24 == day_row(date(2025, 3, 1))
    np.testing.assert_array_equal(hour_rows(_hours("2024-02-29 00:00", "2024-02-29 23:00")),
                                  hour_rows(_hours("2024-02-28 00:00", "2024-02-28 23:00")))
    np.testing.assert_array_equal(hour_rows(_hours("2024-02-28", "2024-02-28")), [58 * 24])
    assert hour_rows(_hours("2024-12-31 23:00", "2024-12-31 23:00"))[0] == 8759
    # consecutive days: 29 February repeats 28 February's day of the file
    np.testing.assert_array_equal(day_rows(date(2024, 2, 27), 4), np.array([57, 58, 58, 59]) * 24)


def test_leap_year_in_an_8784_row_file_has_its_own_29_february():
    assert day_row(date(2024, 3, 1), 8784) == 60 * 24
    assert day_row(date(2024, 2, 29), 8784) == 59 * 24
    np.testing.assert_array_equal(hour_rows(_hours("2024-01-01 00:00", "2024-12-31 23:00"), 8784),
                                  np.arange(8784))


def test_vectorised_and_single_date_agree_and_bad_lengths_are_refused():
    stamps = pd.DatetimeIndex(["2024-02-29 05:30", "2024-07-05 13:00", "2023-11-30 00:10"])
    for n_rows in (8760, 8784):
        expected = [day_row(t.date(), n_rows) + t.hour for t in stamps]
        np.testing.assert_array_equal(hour_rows(stamps, n_rows), expected)
        np.testing.assert_array_equal(hour_rows(pd.Series(stamps), n_rows), expected)
        np.testing.assert_array_equal(epw_rows(stamps, n_rows), expected)
    with pytest.raises(BpsflowError, match="8760 .* or 8784"):
        hour_rows(stamps, 8000)


def test_row_starts_inverts_the_rule():
    for year in (2024, 2025):
        for n_rows in (8760, 8784):
            starts = row_starts(year, n_rows)
            assert len(starts) == n_rows
            read = ~starts.isna()
            np.testing.assert_array_equal(hour_rows(starts[read], n_rows),
                                          np.flatnonzero(read))
    assert row_starts(2024)[59 * 24] == pd.Timestamp("2024-03-01 00:00")
    assert row_starts(2024)[-1] == pd.Timestamp("2024-12-31 23:00")
    assert row_starts(2025, 8784)[59 * 24:60 * 24].isna().all()


def test_schedule_file_steps_follow_the_rule(tmp_path):
    path = tmp_path / "rows.csv"
    np.savetxt(path, np.arange(8760, dtype=float), fmt="%d")
    schedule = Schedule(name="rows", kind="file", file=path, where="test")
    # the value of the hour ending at h + 1 is the file's row of hour h
    values = schedule.steps(date(2024, 2, 28), 3, 1)
    expected = hour_rows(pd.date_range("2024-02-28", periods=72, freq="h"))
    np.testing.assert_array_equal(values, expected)
    np.testing.assert_array_equal(values[24:48], values[:24])           # 29 Feb = 28 Feb
    assert values[48] == 59 * 24                                          # 1 March
    sub_hourly = schedule.steps(date(2024, 3, 1), 1, 4)
    np.testing.assert_array_equal(sub_hourly[3::4], np.arange(59 * 24, 60 * 24))


def test_weather_boundary_and_surrogate_agree_in_a_leap_model_year(tmp_path):
    """Regression: with model.year 2024 the boundary sequences sat 24 rows after the
    surrogate's weather and boundary rows, which refused them ("does not cover")."""
    configs, forcing = {}, {}
    for year in (2024, 2025):
        raw = short_raw()
        raw["model"]["year"] = year
        (tmp_path / str(year)).mkdir()
        config = configs[year] = load_config(write_config(tmp_path / str(year), raw))
        first, last = period_dates(config.model.periods[0], year)
        starts = pd.date_range(first, last + timedelta(days=1), freq="h", inclusive="left")
        weather_rows = epw_rows(starts, read_epw(config.model.weather).n_hours)
        np.testing.assert_array_equal(period_hours(config), weather_rows)

        run_dir = config.run_dir.resolve()
        run_dir.mkdir(parents=True, exist_ok=True)
        write_sequences(draw_sequences(config.model.boundary, period_hours(config)), run_dir)
        samples = sample_columns(config, pd.DataFrame(index=pd.RangeIndex(2, name="instance")))
        cell = build_cell(config, field_values(config, read_idf(config.model.idf), samples))
        forcing[year] = period_forcing(config, cell, config.model.periods[0], samples, run_dir)

    # a TMY year: 5 December reads the same rows in 2024 as in 2025
    np.testing.assert_array_equal(period_hours(configs[2024]), period_hours(configs[2025]))
    np.testing.assert_array_equal(forcing[2024].t_out, forcing[2025].t_out)
    np.testing.assert_array_equal(forcing[2024].wind, forcing[2025].wind)
    for leap, plain in zip(forcing[2024].boundary, forcing[2025].boundary):
        assert (leap is None) == (plain is None)
        if leap is not None:
            np.testing.assert_array_equal(leap, plain)
