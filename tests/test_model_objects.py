"""Model extensions from IDF snippets (``model.idf_objects``) on both backends.

Air exchanges (ZoneInfiltration/ZoneVentilation:DesignFlowRate with their
temperature and wind terms), scheduled internal gains (OtherEquipment with
Schedule:Compact or Schedule:File), the snippets shipped for ``bpsflow
diagnose``, and AR(1) sensor noise for synthetic measurements.
"""

from __future__ import annotations

from datetime import date, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from bpsflow.config import load_config
from bpsflow.diagnosis.extensions import fill_template
from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import model_objects, model_text, parse_idf_text
from bpsflow.surrogate.cell import build_cell, wind_factor, zone_centroid_height
from bpsflow.surrogate.forcing import constant_forcing, period_forcing
from bpsflow.surrogate.network import build_network, simulate
from bpsflow.surrogate.params import field_values, sample_columns
from bpsflow.surrogate.run import simulate_instances
from bpsflow.surrogate.schedules import read_schedule
from bpsflow.synth import Noise, add_noise, ar1_noise

from conftest import ROOT, short_raw, write_config

EXTENSIONS = ROOT / "bpsflow" / "extensions_idf"
HOURS_PER_YEAR = 8760


def weekday_gain_snippet(name: str = "WeekdayGain", schedule: str = "WeekdayOffice",
                         start: str = "09:00", end: str = "17:00", radiant: float = 0.0) -> str:
    """An OtherEquipment on weekdays ``start``–``end`` (design level 0, to be targeted)."""
    return f"""
OtherEquipment, {name}, None, Cell, {schedule}, EquipmentLevel, 0, , , 0, {radiant}, 0;
Schedule:Compact, {schedule}, ,
    Through: 12/31,
    For: Weekdays, Until: {start}, 0, Until: {end}, 1, Until: 24:00, 0,
    For: AllOtherDays, Until: 24:00, 0;
"""


def always_on_gain_snippet(name: str = "ConstantGain", radiant: float = 0.0) -> str:
    return (f"OtherEquipment, {name}, None, Cell, AlwaysOn, EquipmentLevel, 0, , , 0, "
            f"{radiant}, 0;\n")


def targeting(name: str, object_type: str, object_name: str, field: str) -> dict:
    return {"name": name, "distribution": {"type": "constant", "value": 0.0},
            "targets": [{"object": object_type, "name": object_name, "field": field}]}


def no_samplers(raw: dict) -> dict:
    """Measured boundary temperatures instead of sampled sequences (no design needed)."""
    raw["parameters"] = [p for p in raw["parameters"] if p["distribution"]["type"] != "sampler"]
    return raw


#: The names the tests give each extension template's objects on the test cell.
SNIPPET_NAMES = {
    "infiltration_wind.idf": {"object": "DiagnosisWindInfiltration",
                              "schedule": "DiagnosisWindAlwaysOn", "file": ""},
    "envelope_ua.idf": {"object": "DiagnosisExtraConductance",
                        "schedule": "DiagnosisConductanceAlwaysOn", "file": ""},
    "internal_gain_schedule.idf": {"object": "DiagnosisScheduledGain",
                                   "schedule": "DiagnosisGainProfile",
                                   "file": "internal_gain_profile.csv"},
    "solar_aperture.idf": {"object": "DiagnosisSolarAperture",
                           "schedule": "DiagnosisFacadeIrradiance",
                           "file": "facade_irradiance.csv"},
}


def copy_snippet(name: str, folder: Path, zone: str = "Cell") -> Path:
    """An extension template rendered for ``zone`` of the test cell, written to ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    text = fill_template((EXTENSIONS / name).read_text(), {"zone": zone, **SNIPPET_NAMES[name]})
    path = folder / name
    path.write_text(text)
    return path


def write_profile(path: Path, values: np.ndarray) -> Path:
    np.savetxt(path, values, fmt="%.6g")
    return path


def row_of(day: date, hour_ending: int) -> int:
    """Schedule:File row of the hour ending at ``hour_ending`` h on ``day``."""
    return (date(2001, day.month, day.day) - date(2001, 1, 1)).days * 24 + hour_ending - 1


def surrogate_hourly(config, samples: pd.DataFrame, output: str = "heating_power_w"):
    tidy, _ = simulate_instances(config, samples)
    tidy = tidy[tidy["output"] == output]
    return tidy.pivot(index="timestamp", columns="instance", values="value")


def cell_for(config, samples: pd.DataFrame):
    samples = sample_columns(config, samples)
    return build_cell(config, field_values(config, model_objects(config.model), samples)), samples


# Zero design levels: exactly the original model --------------------------------------

def test_zero_design_values_reproduce_the_base_model_exactly(tmp_path):
    raw = no_samplers(short_raw())
    base = load_config(write_config(tmp_path, raw, "base.yaml"))
    folder = tmp_path / "snippets"
    snippets = [copy_snippet(name, folder) for name in
                ("infiltration_wind.idf", "envelope_ua.idf", "internal_gain_schedule.idf",
                 "solar_aperture.idf")]
    rng = np.random.default_rng(3)
    write_profile(folder / "internal_gain_profile.csv", rng.uniform(0, 1, HOURS_PER_YEAR))
    write_profile(folder / "facade_irradiance.csv", rng.uniform(0, 800, HOURS_PER_YEAR))
    weekday = folder / "weekday.idf"
    weekday.write_text(weekday_gain_snippet(radiant=0.6))
    raw["model"]["idf_objects"] = [str(p) for p in (*snippets, weekday)]
    extended = load_config(write_config(tmp_path, raw, "extended.yaml"))
    samples = pd.DataFrame({"south_wall_insulation_conductivity": [0.9, 1.1],
                            "glazing_solar_transmittance": [1.02, 0.97]},
                           index=pd.Index([0, 1], name="instance"))
    before, _ = simulate_instances(base, samples)
    after, ignored = simulate_instances(extended, samples)
    assert set(before["output"]) == {"heating_power_w", "zone_air_temperature_c"}
    pd.testing.assert_frame_equal(before, after, check_exact=True)
    assert not any("Diagnosis" in label or "WeekdayGain" in label for label in ignored)
    # Every variable-flow object is stepped (none folded away), every gain is there.
    cell, _ = cell_for(extended, samples)
    assert [a.name for a in cell.air_exchanges] == ["DiagnosisWindInfiltration"]
    assert sorted(g.name for g in cell.internal_gains) == [
        "DiagnosisScheduledGain", "DiagnosisSolarAperture", "WeekdayGain"]


# Internal gains ---------------------------------------------------------------------

def _gain_config(tmp_path: Path, snippet_text: str, object_name: str):
    folder = tmp_path / "snippets"
    folder.mkdir(parents=True, exist_ok=True)
    snippet = folder / "gain.idf"
    snippet.write_text(snippet_text)
    raw = no_samplers(short_raw())
    raw["model"]["idf_objects"] = [str(snippet)]
    raw["parameters"].append(targeting("gain_w", "OtherEquipment", object_name, "Design Level"))
    return load_config(write_config(tmp_path, raw))


def test_always_on_convective_gain_lowers_heating_by_its_power(tmp_path):
    config = _gain_config(tmp_path, always_on_gain_snippet(), "ConstantGain")
    cell, _ = cell_for(config, pd.DataFrame({"gain_w": [0.0, 200.0, -150.0]},
                                            index=pd.RangeIndex(3, name="instance")))
    forcing = constant_forcing(cell, days=4, t_out=0.0, boundary_c=15.0, heating_c=25.0,
                               cooling_c=40.0)
    result = simulate(cell, build_network(cell), forcing)
    last_day = slice(-24 * forcing.steps_per_hour, None)
    assert np.all(result.power[0, last_day] > 500.0)       # always heating: no clipping
    change = result.power[1:, last_day] - result.power[0, last_day]
    np.testing.assert_allclose(change[0], -200.0, rtol=0.01)
    np.testing.assert_allclose(change[1], 150.0, rtol=0.01)


def test_weekday_compact_schedule_acts_on_weekday_office_hours_only(tmp_path):
    config = _gain_config(tmp_path, weekday_gain_snippet(), "WeekdayGain")
    cell, _ = cell_for(config, pd.DataFrame({"gain_w": [0.0, 200.0]},
                                            index=pd.RangeIndex(2, name="instance")))
    first = date(2025, 1, 1)                                  # a Wednesday
    forcing = constant_forcing(cell, days=7, t_out=0.0, boundary_c=15.0, heating_c=25.0,
                               cooling_c=40.0, first=first)
    result = simulate(cell, build_network(cell), forcing)
    tph = forcing.steps_per_hour
    change = (result.power[1] - result.power[0]).reshape(7, 24, tph).mean(axis=2)
    expected = np.zeros((7, 24))
    for d in range(7):
        if (first + timedelta(days=d)).weekday() < 5:
            expected[d, 9:17] = -200.0                        # hours 09:00–17:00
    np.testing.assert_allclose(change, expected, atol=1e-6 * 200)
    assert [(first + timedelta(days=d)).strftime("%a") for d in range(7)
            if change[d].min() < -100] == ["Wed", "Thu", "Fri", "Mon", "Tue"]


def test_radiant_gain_reaches_the_faces_and_the_energy_balance_closes(tmp_path):
    config = _gain_config(tmp_path, always_on_gain_snippet(radiant=0.7), "ConstantGain")
    samples = pd.DataFrame({"gain_w": [0.0, 400.0]}, index=pd.RangeIndex(2, name="instance"))
    cell, samples = cell_for(config, samples)
    forcing = period_forcing(config, cell, config.model.periods[0], samples)
    network = build_network(cell)
    result = simulate(cell, network, forcing, account=True)
    e = result.energy
    seconds = forcing.steps * 3600.0 / forcing.steps_per_hour
    np.testing.assert_allclose(e["internal"], [0.0, 400.0 * seconds], rtol=1e-12)
    inflow = e["hvac"] + e["solar"] + e["internal"] + e["ventilation"] + e["exterior"] \
        + e["boundary"]
    scale = np.abs(e["hvac"]) + e["solar"] + e["internal"] + np.abs(e["exterior"])
    np.testing.assert_allclose(inflow, e["stored"], atol=1e-8 * scale.max())
    # The radiant part is split by area x thermal absorptance, window included.
    from bpsflow.surrogate.network import _Stepper

    stepper = _Stepper(cell, network, forcing, 600.0, account=False)
    gains = stepper._internal_gains(slice(0, 6))[1, 0]
    faces = network.inside + [network.pane_in]
    weights = np.array([s.area * s.emissivity_in[1] for s in cell.opaque]
                       + [cell.window.area * cell.window.emissivity_in[1]])
    np.testing.assert_allclose(gains[faces], 0.7 * 400.0 * weights / weights.sum(), rtol=1e-12)
    assert gains[network.AIR] == pytest.approx(0.3 * 400.0)


# Air exchanges ----------------------------------------------------------------------

def _heating_at(raw: dict, setpoint_c: float) -> dict:
    raw["model"]["tests"] = [{"name": "H", "period": "winter", "start": "12-05", "days": 2,
                              "warmup_days": 0, "mode": "heating", "setpoint_c": setpoint_c,
                              "outputs": ["heating_power_w"]}]
    return raw


def test_wind_infiltration_adds_rho_cp_flow_delta_t_hour_by_hour(tmp_path):
    setpoint = 35.0
    raw = _heating_at(no_samplers(short_raw()), setpoint)
    raw["model"]["idf_objects"] = [str(copy_snippet("infiltration_wind.idf", tmp_path / "s"))]
    raw["parameters"].append(targeting("wind_flow", "ZoneInfiltration:DesignFlowRate",
                                       "DiagnosisWindInfiltration", "Design Flow Rate"))
    config = load_config(write_config(tmp_path, raw))
    design = 0.01                                             # m³/s per m/s
    samples = pd.DataFrame({"wind_flow": [0.0, design]}, index=pd.Index([0, 1], name="instance"))
    power = surrogate_hourly(config, samples)
    assert (power[0] > 50.0).all()                            # heating throughout: no clipping
    change = (power[1] - power[0]).to_numpy()
    # Closed form from the period's per-step weather: the local wind at the zone
    # centroid (mid-height of the 3.658 m cell, suburbs terrain) drives the flow.
    cell, samples = cell_for(config, samples)
    forcing = period_forcing(config, cell, config.model.periods[0], samples)
    local = (270.0 / 10.0) ** 0.14 * (3.658 / 2 / 370.0) ** 0.22
    humidity = forcing.humidity[0]                            # kg/kg
    rho = forcing.pressure[0] / (287.05 * (forcing.t_out[0] + 273.15) * (1 + 1.608 * humidity))
    cp = 1006.0 + 1860.0 * humidity
    watts = rho * cp * design * local * forcing.wind[0] * (setpoint - forcing.t_out[0])
    hourly = watts.reshape(-1, forcing.steps_per_hour).mean(axis=1)
    first = (date(2025, 12, 5) - forcing.first).days * 24
    expected = hourly[first:first + len(change)]
    assert expected.min() > 50.0
    np.testing.assert_allclose(change, expected, rtol=0.01)


def test_zone_centroid_and_local_wind_factor(tmp_path):
    config = load_config(write_config(tmp_path, no_samplers(short_raw())))
    surfaces = model_objects(config.model).of_type("BuildingSurface:Detailed")
    assert zone_centroid_height(surfaces) == pytest.approx(3.658 / 2, abs=1e-3)
    assert wind_factor(3.658 / 2, "Suburbs", "HEIGHTADJUST") == pytest.approx(
        (270 / 10) ** 0.14 * (1.829 / 370) ** 0.22, rel=1e-3)


def test_ventilation_temperature_and_wind_terms_change_the_flow(tmp_path):
    """The model's own ZoneVentilation now takes its B, C and D terms too."""
    raw = _heating_at(no_samplers(short_raw()), 35.0)
    raw["parameters"].append(targeting("vent_b", "ZoneVentilation:DesignFlowRate",
                                       "AirInjection", "Temperature Term Coefficient"))
    config = load_config(write_config(tmp_path, raw))
    samples = pd.DataFrame({"vent_b": [0.0, 0.05]}, index=pd.Index([0, 1], name="instance"))
    cell, _ = cell_for(config, samples)
    assert [a.name for a in cell.air_exchanges] == ["AirInjection"]
    assert cell.ventilation_m3s.tolist() == [0.0, 0.0]
    power = surrogate_hourly(config, samples)
    # With B = 0.05 /K and |ΔT| ≈ 20 K the 0.01 m³/s injection doubles: ≈ +240 W.
    change = (power[1] - power[0]).to_numpy()
    assert 150.0 < change.mean() < 350.0


# Config, targets, errors ------------------------------------------------------------

def test_snippet_paths_resolve_against_their_config_and_extends_appends(tmp_path):
    snippet = copy_snippet("envelope_ua.idf", tmp_path / "base" / "snips")
    raw = no_samplers(short_raw())
    raw["model"]["idf_objects"] = ["snips/envelope_ua.idf"]
    base_path = write_config(tmp_path / "base", raw, "base.yaml")
    other = copy_snippet("infiltration_wind.idf", tmp_path / "child" / "more")
    child = tmp_path / "child" / "child.yaml"
    child.write_text(yaml.safe_dump({"extends": "../base/base.yaml",
                                     "model": {"idf_objects": ["more/infiltration_wind.idf"]}}))
    assert load_config(base_path).model.idf_objects == [snippet.resolve()]
    assert load_config(child).model.idf_objects == [snippet.resolve(), other.resolve()]


def test_missing_snippet_file_is_named(tmp_path):
    raw = no_samplers(short_raw())
    raw["model"]["idf_objects"] = [str(EXTENSIONS / "envelope_ua.idf"), "nowhere/gone.idf"]
    with pytest.raises(BpsflowError) as caught:
        load_config(write_config(tmp_path, raw))
    message = str(caught.value)
    assert "model.idf_objects[1]" in message and "gone.idf" in message
    assert "not found" in message


@pytest.mark.parametrize("snippet, words", [
    ("ZoneInfiltration:DesignFlowRate, Leak, Cell, AlwaysOn, AirChanges/Hour, , , , 0.5;",
     ["ZoneInfiltration:DesignFlowRate 'Leak'", "Design Flow Rate Calculation Method",
      "AirChanges/Hour"]),
    ("OtherEquipment, Heater, Electricity, Cell, AlwaysOn, EquipmentLevel, 100;",
     ["OtherEquipment 'Heater'", "Fuel Type", "Electricity"]),
    ("OtherEquipment, Heater, None, Cell, AlwaysOn, Watts/Area, , 2;",
     ["OtherEquipment 'Heater'", "Design Level Calculation Method"]),
    ("OtherEquipment, Heater, None, Cell, Ramp, EquipmentLevel, 100;\n"
     "Schedule:Compact, Ramp, , Through: 12/31, For: AllDays, Interpolate: Linear, "
     "Until: 24:00, 1;", ["Schedule:Compact 'Ramp'", "Interpolate:No"]),
    ("OtherEquipment, Heater, None, Elsewhere, AlwaysOn, EquipmentLevel, 100;",
     ["OtherEquipment 'Heater'", "Elsewhere"]),
])
def test_unsupported_variants_name_the_object_and_field(tmp_path, snippet, words):
    path = tmp_path / "bad.idf"
    path.write_text(snippet)
    raw = no_samplers(short_raw())
    raw["model"]["idf_objects"] = [str(path)]
    config = load_config(write_config(tmp_path, raw))
    with pytest.raises(BpsflowError) as caught:
        simulate_instances(config, pd.DataFrame(index=pd.Index([0], name="instance")))
    message = str(caught.value)
    assert str(path) in message
    for word in words:
        assert word in message


def test_snippet_may_not_redefine_model_objects(tmp_path):
    path = tmp_path / "dup.idf"
    path.write_text("Schedule:Constant, AlwaysOn, , 1;\n")
    raw = no_samplers(short_raw())
    raw["model"]["idf_objects"] = [str(path)]
    config = load_config(write_config(tmp_path, raw))
    with pytest.raises(BpsflowError, match="AlwaysOn.*already defined"):
        model_objects(config.model)


def test_schedule_file_names_resolve_next_to_their_snippet(tmp_path):
    folder = tmp_path / "elsewhere"
    snippet = copy_snippet("internal_gain_schedule.idf", folder)
    raw = no_samplers(short_raw())
    raw["model"]["idf_objects"] = [str(snippet)]
    config = load_config(write_config(tmp_path, raw))
    objects = parse_idf_text(model_text(config.model))
    schedule = objects.find("Schedule:File", "DiagnosisGainProfile")
    assert schedule.get("File Name") == str((folder / "internal_gain_profile.csv").resolve())
    # The base model's own Schedule:File names are made absolute the same way.
    floor = objects.find("Schedule:File", "FloorBoundaryTemperature")
    assert Path(floor.get("File Name")) == ROOT / "sample_idf" / "boundary_temperatures.csv"
    # ... and the surrogate reads the CSV there, naming the schedule when it is missing.
    with pytest.raises(BpsflowError, match="DiagnosisGainProfile.*not found"):
        simulate_instances(config, pd.DataFrame(index=pd.Index([0], name="instance")))


def test_compact_schedule_values_at_step_ends(tmp_path):
    idf = parse_idf_text("""
Schedule:Compact, Mixed, ,
    Through: 6/30, For: AllDays, Until: 24:00, 5,
    Through: 12/31,
    For: Weekdays SummerDesignDay, Until: 08:30, 0, Until: 18:00, 1, Until: 24:00, 0,
    For: Saturday, Until: 12:00, 2, Until: 24:00, 0,
    For: AllOtherDays, Until: 24:00, 3;
""", tmp_path / "s.idf")
    schedule = read_schedule(idf, "Mixed", "test")
    friday = date(2025, 12, 5)
    values = schedule.steps(friday, 3, 6).reshape(3, 24, 6)          # Fri, Sat, Sun
    # Friday: 0 up to and including the step ending 08:30, 1 from 08:40 to 18:00.
    assert values[0, 8].tolist() == [0, 0, 0, 1, 1, 1]
    assert values[0, 17].tolist() == [1] * 6 and values[0, 18].tolist() == [0] * 6
    assert values[1, 11].tolist() == [2] * 6 and values[1, 12].tolist() == [0] * 6
    assert np.all(values[2] == 3)
    assert np.all(schedule.steps(date(2025, 3, 3), 1, 4) == 5)


# AR(1) sensor noise -----------------------------------------------------------------

@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9])
def test_ar1_noise_has_the_set_autocorrelation_and_std(phi):
    noise = Noise(kind="absolute", bound=0.3, autocorrelation=phi)
    values = np.zeros(200_000)
    noisy = add_noise(values, noise, np.random.default_rng(11))
    lag1 = np.corrcoef(noisy[:-1], noisy[1:])[0, 1]
    assert lag1 == pytest.approx(phi, abs=0.05)
    assert noisy.std() == pytest.approx(0.1, rel=0.05 if phi > 0.5 else 0.02)


def test_ar1_noise_restarts_at_gaps_and_zero_keeps_white_noise():
    draws = np.random.default_rng(5).standard_normal(10)
    assert ar1_noise(draws, 0.0) is draws
    out = ar1_noise(draws, 0.8, starts=np.array([4]))
    assert out[0] == draws[0] and out[4] == draws[4]
    assert out[5] == pytest.approx(0.8 * out[4] + np.sqrt(1 - 0.64) * draws[5])
    with pytest.raises(ValueError):
        Noise(kind="absolute", bound=0.1, autocorrelation=1.0)


# EnergyPlus -------------------------------------------------------------------------

@pytest.mark.energyplus
def test_snippet_fields_are_targetable_on_both_backends(tmp_path):
    from bpsflow.simulation.energyplus.engine import find_energyplus, idd_path
    from bpsflow.simulation.energyplus.instances import check_model, open_idf, write_instance

    folder = tmp_path / "ext"
    snippet = copy_snippet("internal_gain_schedule.idf", folder)
    write_profile(folder / "internal_gain_profile.csv", np.ones(HOURS_PER_YEAR))
    raw = no_samplers(short_raw())
    raw["model"]["idf_objects"] = [str(snippet)]
    raw["parameters"].append(targeting("scheduled_gain_w", "OtherEquipment",
                                       "DiagnosisScheduledGain", "Design Level"))
    raw["parameters"].append(targeting("gain_radiant", "OtherEquipment",
                                       "DiagnosisScheduledGain", "Fraction Radiant"))
    config = load_config(write_config(tmp_path, raw))
    idd = idd_path(find_energyplus())
    targets = check_model(config, idd).targets
    assert [r.object_name for r in targets.idf_fields["scheduled_gain_w"]] == [
        "DiagnosisScheduledGain"]
    sample = {p.name: float(p.distribution.nominal) for p in config.parameters}
    sample.update(scheduled_gain_w=-437.5, gain_radiant=0.25)
    files = write_instance(config, sample, tmp_path / "instance", idd)
    idf = open_idf(files.idfs["winter"], idd)
    gain = idf.getobject("OTHEREQUIPMENT", "DiagnosisScheduledGain")
    assert gain.Design_Level == pytest.approx(-437.5)
    assert gain.Fraction_Radiant == pytest.approx(0.25)
    profile = idf.getobject("SCHEDULE:FILE", "DiagnosisGainProfile")
    assert profile.File_Name == str((folder / "internal_gain_profile.csv").resolve())
    cell, _ = cell_for(config, pd.DataFrame([sample], index=pd.Index([7], name="instance")))
    assert cell.internal_gains[0].design_w.tolist() == [-437.5]
    assert cell.internal_gains[0].fraction_radiant.tolist() == [0.25]
    # A target on a snippet object that does not exist is named on both backends.
    raw["parameters"][-1]["targets"][0]["name"] = "NoSuchGain"
    bad = load_config(write_config(tmp_path, raw, "bad.yaml"))
    with pytest.raises(BpsflowError, match="NoSuchGain.*internal_gain_schedule.idf"):
        check_model(bad, idd)
    with pytest.raises(BpsflowError, match="NoSuchGain.*internal_gain_schedule.idf"):
        simulate_instances(bad, pd.DataFrame(index=pd.Index([0], name="instance")))


@pytest.mark.energyplus
def test_energyplus_and_surrogate_agree_on_the_extensions(tmp_path):
    """Two days (Friday 12-05 and Saturday 12-06, 2025), heating at 35 °C.

    Instance 1 adds wind-driven infiltration (0.01 m³/s per m/s); instance 2 a
    300 W convective gain on weekdays 01:00–07:00 (Schedule:Compact) and a
    300 W gain read from a Schedule:File next to its snippet (Saturday,
    hours ending 20:00–22:00). The change each causes in the hourly heating
    power must agree between the backends.
    """
    from bpsflow.simulation.energyplus import run_instance
    from bpsflow.simulation.energyplus.engine import find_energyplus, idd_path

    folder = tmp_path / "ext"
    wind = copy_snippet("infiltration_wind.idf", folder)
    profile_snippet = copy_snippet("internal_gain_schedule.idf", folder)
    profile = np.zeros(HOURS_PER_YEAR)
    saturday = date(2025, 12, 6)
    profile[[row_of(saturday, h) for h in (20, 21, 22)]] = 1.0
    write_profile(folder / "internal_gain_profile.csv", profile)
    weekday = folder / "weekday_night.idf"
    weekday.write_text(weekday_gain_snippet(schedule="WeekdayNight", start="01:00", end="07:00"))
    raw = no_samplers(short_raw())
    raw["model"]["periods"] = [{"name": "winter", "start": "12-05", "end": "12-06"}]
    raw["model"]["tests"] = [{"name": "H", "period": "winter", "start": "12-05", "days": 2,
                              "warmup_days": 0, "mode": "heating", "setpoint_c": 35.0,
                              "outputs": ["heating_power_w"]}]
    raw["model"]["idf_objects"] = [str(wind), str(weekday), str(profile_snippet)]
    raw["parameters"] += [
        targeting("wind_flow", "ZoneInfiltration:DesignFlowRate", "DiagnosisWindInfiltration",
                  "Design Flow Rate"),
        targeting("weekday_gain_w", "OtherEquipment", "WeekdayGain", "Design Level"),
        targeting("profile_gain_w", "OtherEquipment", "DiagnosisScheduledGain", "Design Level")]
    config = load_config(write_config(tmp_path, raw))
    nominal = {p.name: float(p.distribution.nominal) for p in config.parameters}
    changes = [{}, {"wind_flow": 0.01}, {"weekday_gain_w": 300.0, "profile_gain_w": 300.0}]
    binary = find_energyplus()
    idd = idd_path(binary)
    energyplus = {}
    for label, change in enumerate(changes):
        record, frame = run_instance(config, label, {**nominal, **change}, tmp_path / "run",
                                     binary, idd)
        assert record.status == "ok", record.error
        energyplus[label] = frame.set_index("timestamp")["value"]
    energyplus = pd.DataFrame(energyplus)
    samples = pd.DataFrame([{**nominal, **c} for c in changes],
                           index=pd.Index(range(len(changes)), name="instance"))
    surrogate = surrogate_hourly(config, samples).loc[energyplus.index]
    assert len(energyplus) == 48
    day = (energyplus.index - pd.Timedelta(hours=1)).date
    for label in (1, 2):
        ep_change = energyplus[label] - energyplus[0]
        su_change = surrogate[label] - surrogate[0]
        ep_daily, su_daily = ep_change.groupby(day).sum(), su_change.groupby(day).sum()
        if label == 1:
            np.testing.assert_allclose(su_daily, ep_daily, rtol=0.10)
            assert (ep_change > 100).all() and (su_change > 100).all()
        else:
            # The same hours on the same days: Friday night (weekday), Saturday evening (file).
            for change in (ep_change, su_change):
                active = change.index[change.abs() > 1.0]
                hours = [(t.strftime("%a"), t.hour) for t in active]
                assert hours == [("Fri", h) for h in range(2, 8)] + [
                    ("Sat", h) for h in (20, 21, 22)]
                np.testing.assert_allclose(change[active], -300.0, rtol=0.01)
            np.testing.assert_allclose(su_daily, ep_daily, rtol=0.10)
