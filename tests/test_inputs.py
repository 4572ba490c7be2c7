"""Instance inputs: weather sensor errors, boundary sequences, setpoint schedules, SQLite timestamps."""

from __future__ import annotations

import numpy as np
import pytest

from bpsflow.boundary import draw_sequences, period_hours, read_boundary_file
from bpsflow.config import load_config
from bpsflow.simulation.setpoints import (
    COOLING_OFF_C,
    HEATING_OFF_C,
    day_setpoints,
    setpoint_schedules,
)
from bpsflow.weather import perturb, read_epw, write_epw


@pytest.fixture
def config(short_config):
    return load_config(short_config)


def test_weather_errors_keep_file_consistent(config, tmp_path):
    epw = read_epw(config.model.weather)
    changed = perturb(epw, {"global_horizontal_radiation": ("relative", 1.05),
                            "dew_point_temperature": ("additive", 30.0),
                            "wind_speed": ("additive", -100.0)})
    ghi, dhi = epw.columns["global_horizontal_radiation"], epw.columns["diffuse_horizontal_radiation"]
    sunny = (ghi - dhi) > 50
    # beam horizontal scaled as GHI' - DHI, so DNI scales by the same ratio
    ratio = (1.05 * ghi[sunny] - dhi[sunny]) / (ghi[sunny] - dhi[sunny])
    np.testing.assert_allclose(changed["direct_normal_radiation"][sunny],
                               epw.columns["direct_normal_radiation"][sunny] * ratio)
    assert (changed["dew_point_temperature"] <= epw.columns["dry_bulb_temperature"]).all()
    assert (changed["wind_speed"] == 0).all()
    assert changed["relative_humidity"].max() == pytest.approx(100.0)
    path = write_epw(epw, changed, tmp_path / "x.epw")
    again = read_epw(path)
    np.testing.assert_allclose(again.columns["global_horizontal_radiation"],
                               1.05 * ghi, atol=0.051)


def test_boundary_sequences_are_latin_hypercube_per_time_step(config):
    boundary = config.model.boundary.model_copy(update={"sequences": 40, "sensor_std_c": 0.2})
    hours = period_hours(config)
    assert len(hours) == 4 * 24
    sequences = draw_sequences(boundary, hours)
    measured = read_boundary_file(boundary.file, ("floor_c",))["floor_c"].to_numpy()[hours]
    values = sequences.values[sequences.surfaces.index("floor")]  # (sequences, hours)
    from scipy import stats

    strata = np.floor(stats.norm.cdf((values - measured[None, :]) / 0.2) * 40).astype(int)
    for k in range(len(hours)):  # exactly one draw per stratum at every time step
        assert sorted(strata[:, k]) == list(range(40))
    # independent across time steps: neighbouring hours are not in the same stratum order
    assert abs(np.corrcoef(strata[:, 0], strata[:, 1])[0, 1]) < 0.5


def test_setpoint_profiles_follow_the_test_mode(config):
    heating_st, free = config.model.tests
    heat, cool = day_setpoints(heating_st)
    assert heat == [(8, 20.0), (18, 30.0), (24, 20.0)]
    assert cool == [(24, COOLING_OFF_C)]
    assert day_setpoints(free) == ([(24, HEATING_OFF_C)], [(24, COOLING_OFF_C)])
    # a window within the day, and one that starts at midnight, are kept as written
    for start, end, expected in ((12, 14, [(12, 30.0), (14, 20.0), (24, 30.0)]),
                                 (0, 6, [(6, 20.0), (24, 30.0)]),
                                 (22, 24, [(22, 30.0), (24, 20.0)])):
        moved = heating_st.model_copy(update={"setback_start_hour": start,
                                              "setback_end_hour": end})
        assert day_setpoints(moved)[0] == expected
    heating_text, cooling_text = setpoint_schedules(config, config.model.periods[0])
    assert "Through: 12/06" in heating_text and "Until: 18:00,\n  30" in heating_text
    assert heating_text.rstrip().endswith(";") and "Through: 12/31" in heating_text
    assert f"{HEATING_OFF_C:g}" in heating_text.split("Through: 12/06")[1]
