"""Candidate extensions in their natural free shapes, nested at zero, on both backends.

* ``infiltration``: EnergyPlus's law A + B|ΔT| + C·V + D·V², any subset of
  the terms free;
* ``internal_gain_schedule``: a radiant fraction besides the level, and
  blocks on single days of the week;
* ``thermal_mass``: an InternalMass whose area is fitted.

"Nested at zero": with the new parameters at 0 the extended model predicts
what the original model predicts (exactly on the surrogate for the
infiltration and gain; within a stated tolerance where EnergyPlus needs a
token object, and for EnergyPlus's own reporting).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from bpsflow.config import Config, load_config
from bpsflow.diagnosis.extensions import (
    DAY_TYPES,
    EXTENSIONS,
    block_profile,
    extend_config,
    free_parameters,
    gain_blocks,
    law_text,
    new_parameters,
    profile_schedule,
    term_subsets,
    year_hours,
)
from bpsflow.diagnosis.fitting import output_simulator
from bpsflow.errors import BpsflowError

ROOT = Path(__file__).resolve().parents[1]
DIAGNOSIS = ROOT / "configs" / "diagnosis.yaml"
OUTPUT = "heating_power_w"
#: Four days after three of warm-up, inside the base config's period.
HOURS = pd.date_range("2025-11-04 01:00", periods=24 * 4, freq="h")
INFILTRATION_TERMS = {"infiltration_a_m3s": 0.01, "infiltration_b_m3s_per_k": 0.001,
                      "infiltration_c_m3s_per_ms": 0.004, "infiltration_d_m3s_per_m2s2": 0.001}


def base_config(folder: Path, backend: str) -> Config:
    """configs/diagnosis.yaml over 8 days of November on ``backend``."""
    raw = {"extends": str(DIAGNOSIS),
           "model": {"backend": backend,
                     "periods": [{"name": "diagnosis", "start": "11-01", "end": "11-08"}],
                     "tests": [{"name": "H-DG", "period": "diagnosis", "start": "11-01",
                                "days": 8, "warmup_days": 3, "mode": "heating",
                                "setpoint_c": 30.0, "outputs": [OUTPUT]}]},
           "execution": {"jobs": 2, "run_dir": str(folder / "base_run")}}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "base.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return load_config(path)


def nominal(config: Config) -> dict[str, float]:
    return {p.name: float(p.distribution.nominal) for p in config.parameters}


def nested_point(config: Config, extended: Config) -> dict[str, float]:
    """``config``'s nominal inputs with every extension parameter at its nesting value."""
    return {**nominal(config), **{p.name: p.provenance["nested_at"] for p in extended.parameters
                                  if p.group == "extension"}}


def simulate(config: Config, rows: list[dict], work: Path, backend: str) -> np.ndarray:
    """Heating power (W) of each row over :data:`HOURS`, shape (rows, hours)."""
    return output_simulator(config, OUTPUT, HOURS, backend=backend, work_dir=work)(
        pd.DataFrame(rows))


def daily_swing(power: np.ndarray) -> np.ndarray:
    days = power.reshape(-1, 24)
    return days.max(axis=1) - days.min(axis=1)


def all_extensions(config: Config, folder: Path) -> Config:
    """``config`` with every new extension: infiltration (4 terms), gain (01-06 h), thermal
    mass, scheduled air exchange (19-23 h)."""
    hours = year_hours(config.model.year)
    start_hour = (hours - pd.Timedelta(hours=1)).hour
    gain_on = pd.Series(((start_hour >= 1) & (start_hour < 6)).astype(float), index=hours)
    airing_on = pd.Series(((start_hour >= 19) & (start_hour < 23)).astype(float), index=hours)
    extended = extend_config(config, EXTENSIONS["infiltration"], folder / "infiltration",
                             output=OUTPUT)
    extended = extend_config(extended, EXTENSIONS["internal_gain_schedule"], folder / "gain",
                             gain_on, output=OUTPUT)
    extended = extend_config(extended, EXTENSIONS["scheduled_air_exchange"], folder / "air",
                             airing_on, output=OUTPUT)
    return extend_config(extended, EXTENSIONS["thermal_mass"], folder / "mass", output=OUTPUT)


@pytest.fixture(scope="module")
def surrogate_base(tmp_path_factory) -> Config:
    return base_config(tmp_path_factory.mktemp("extensions_base"), "surrogate")


# ---------------------------------------------------------------------------
# The catalogue and its helpers


def test_infiltration_terms_choose_the_free_parameters(surrogate_base, tmp_path):
    extension = EXTENSIONS["infiltration"]
    assert [(p.name, p.field, p.lower) for p in extension.parameters] == [
        ("infiltration_a_m3s", "Constant Term Coefficient", 0.0),
        ("infiltration_b_m3s_per_k", "Temperature Term Coefficient", 0.0),
        ("infiltration_c_m3s_per_ms", "Velocity Term Coefficient", 0.0),
        ("infiltration_d_m3s_per_m2s2", "Velocity Squared Term Coefficient", 0.0)]
    subsets = term_subsets(extension)
    assert len(subsets) == 15 and subsets[0] == ("A",) and subsets[-1] == ("A", "B", "C", "D")
    assert [p.name for p in free_parameters(extension, ("d", "infiltration_a_m3s"))] == [
        "infiltration_a_m3s", "infiltration_d_m3s_per_m2s2"]
    with pytest.raises(ValueError, match="terms \\['e'\\]"):
        free_parameters(extension, ("E",))
    extended = extend_config(surrogate_base, extension, tmp_path, variant=3, output=OUTPUT,
                             terms=("A", "C"))
    added = [p for p in extended.parameters if p.group == "extension"]
    assert [p.name for p in added] == ["infiltration_a_m3s_v3", "infiltration_c_m3s_per_ms_v3"]
    assert [p.provenance["term"] for p in added] == ["A", "C"]
    text = extended.model.idf_objects[-1].read_text()
    assert "1,                           !- Design Flow Rate" in text


def test_law_text_names_the_fitted_terms():
    assert law_text({"infiltration_a_m3s": 0.012, "infiltration_b_m3s_per_k": 0.0,
                     "infiltration_d_m3s_per_m2s2_v2": 0.0031}) == "flow = 0.012 + 0.0031·V² m³/s"
    assert law_text({"infiltration_b_m3s_per_k": 0.00125, "infiltration_c_m3s_per_ms": 0.004}) \
        == "flow = 0.00125·|ΔT| + 0.004·V m³/s"
    assert law_text({}) == "flow = 0 m³/s"


def test_an_extension_is_at_zero_only_when_every_size_parameter_is_at_its_nested_value():
    """A fit that leaves the level at 0 has only moved the existing inputs: no cause."""
    from types import SimpleNamespace

    from bpsflow.diagnosis.workflow import null_sized

    gain = new_parameters(EXTENSIONS["internal_gain_schedule"], "gain", variant=2)
    mass = new_parameters(EXTENSIONS["thermal_mass"], "mass")
    law = new_parameters(EXTENSIONS["infiltration"], "leak")

    def at(parameters, *values):
        return SimpleNamespace(named={p.name: v for p, v in zip(parameters, values)})

    # a radiant fraction or a thickness shapes an effect, it does not size it
    assert null_sized(at(gain, 0.0, 0.6), gain)
    assert not null_sized(at(gain, 15.0, 0.0), gain)
    assert null_sized(at(mass, 0.0, 0.3), mass)
    assert not null_sized(at(mass, 2.0, 0.1), mass)
    assert null_sized(at(law, 0.0, 0.0, 0.0, 0.0), law)
    assert not null_sized(at(law, 0.0, 0.0, 0.0, 1e-4), law)


def test_single_day_block_profile_and_schedule_follow_the_day_of_week():
    profile = block_profile("saturday", 10, 14)
    assert profile.index.names == ["day_of_week", "hour"]
    assert profile["profile"].sum() == 4.0
    assert profile.loc[(5, 10), "profile"] == 1.0 and profile.loc[(5, 14), "profile"] == 0.0
    schedule = profile_schedule(profile, 2025)
    start = schedule.index - pd.Timedelta(hours=1)
    on = (start.day_of_week == 5) & (start.hour >= 10) & (start.hour < 14)
    assert (schedule.to_numpy() == on.astype(float)).all()
    assert schedule.sum() == 4 * 52         # 2025 has 52 Saturdays in its 8760 hours
    weekdays = profile_schedule(block_profile("weekdays", 9, 17), 2025)
    assert weekdays.sum() == 8 * 261
    assert set(DAY_TYPES) >= {"weekdays", "weekends", "all days", "monday", "sunday"}


def test_gain_blocks_recover_a_saturday_block_from_a_synthetic_residual():
    """A Saturday 10-14 h gain, confounded with a fitted response, is the first block."""
    rng = np.random.default_rng(4)
    hours = pd.date_range("2025-11-01 01:00", periods=900, freq="h")
    start = hours - pd.Timedelta(hours=1)
    saturday = np.asarray((start.day_of_week == 5) & (start.hour >= 10) & (start.hour < 14))
    solar_like = np.clip(np.sin(np.pi * (np.asarray(start.hour) - 6) / 12), 0, None)
    jacobian = np.column_stack([solar_like, rng.normal(size=900)])
    # heating output: a gain of 120 W lowers it; the calibration absorbed some into "solar"
    residual = -120.0 * saturday + 30.0 * solar_like + rng.normal(0, 15.0, 900)
    blocks = gain_blocks(pd.Series(residual, index=hours), -1.0, jacobian, count=3)
    first = blocks[0][1]
    assert (first["day_type"], first["start_hour"], first["end_hour"]) == ("saturday", 10, 14)
    assert first["level"] == pytest.approx(120.0, rel=0.1)
    # the screen is the exact least squares of each block with the base
    design = np.column_stack([saturday, np.ones(900), jacobian])
    expected = np.linalg.lstsq(design, residual, rcond=None)[0][0]
    assert first["level"] == pytest.approx(-expected, rel=1e-9)
    assert blocks[0][0]["profile"].sum() == 4.0


# ---------------------------------------------------------------------------
# Nested at zero on the surrogate


def test_new_extensions_are_nested_at_zero_on_the_surrogate(surrogate_base, tmp_path):
    """Every new parameter at 0 reproduces the original model; each one moves the output."""
    config = surrogate_base
    extended = all_extensions(config, tmp_path / "ext")
    zero = nested_point(config, extended)
    rows = [zero, {**zero, "scheduled_gain_radiant_fraction": 0.6}]
    rows += [{**zero, name: value} for name, value in INFILTRATION_TERMS.items()]
    rows += [{**zero, "scheduled_gain_w": 300.0},
             {**zero, "scheduled_gain_w": 300.0, "scheduled_gain_radiant_fraction": 0.6},
             {**zero, "internal_mass_area_m2": 60.0},
             {**zero, "scheduled_air_flow_m3s": 0.05}]
    predicted = simulate(extended, rows, tmp_path / "runs", "surrogate")
    original = simulate(config, [nominal(config)], tmp_path / "runs0", "surrogate")[0]
    # infiltration and gain are exactly nested; the mass keeps a token 0.001 m2
    np.testing.assert_allclose(predicted[1], predicted[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(predicted[0], original, rtol=0, atol=0.05)
    without_mass = extend_config(
        extend_config(config, EXTENSIONS["infiltration"], tmp_path / "e2" / "i", output=OUTPUT),
        EXTENSIONS["internal_gain_schedule"], tmp_path / "e2" / "g",
        pd.Series(0.0, index=year_hours(config.model.year)), output=OUTPUT)
    np.testing.assert_allclose(simulate(without_mass, [zero], tmp_path / "runs2",
                                        "surrogate")[0], original, rtol=0, atol=1e-9)
    for row, name in zip(predicted[2:6], INFILTRATION_TERMS):
        assert np.mean(row - original) > 5.0, name          # a leak needs more heating
    level, radiant, mass = predicted[6], predicted[7], predicted[8]
    start_hour = (HOURS - pd.Timedelta(hours=1)).hour
    on, after = (start_hour >= 1) & (start_hour < 6), (start_hour >= 6) & (start_hour < 9)
    heating = original > 150.0      # sunny hours need no heating: a gain cannot lower it
    assert (on & heating).sum() >= 15
    assert level[on & heating] - original[on & heating] == pytest.approx(-300.0, abs=1.0)
    # a radiant part warms the faces first: less of it shows in the on-hours' power,
    # more after them
    assert np.mean(radiant[on] - level[on]) > 10.0
    assert np.mean(radiant[after] - level[after]) < -2.0
    assert (daily_swing(mass) < daily_swing(original)).all()
    # an outdoor air flow of 0.05 m3/s while on: a loss of about rho c_p 0.05 (60 W/K) x dT
    airing = predicted[9] - original
    airing_on = (start_hour >= 19) & (start_hour < 23)
    assert 300.0 < np.mean(airing[airing_on & heating]) < 2000.0
    assert np.mean(np.abs(airing[(start_hour >= 9) & (start_hour < 17)])) < \
        0.1 * np.mean(airing[airing_on & heating])


def test_infiltration_d_term_reproduces_a_hidden_velocity_squared_leak(surrogate_base,
                                                                       tmp_path):
    """Only D free, at the hidden leak's value: the same predictions as the hidden object."""
    config = surrogate_base
    zone = "Cell"      # the shipped test cell's zone, named in this test only
    hidden = tmp_path / "hidden.idf"
    hidden.write_text(f"""
ZoneInfiltration:DesignFlowRate,
    HiddenSquareLawLeak, {zone}, HiddenLeakAlwaysOn, Flow/Zone,
    0.5, , , ,
    0, 0, 0, 0.008;

Schedule:Constant, HiddenLeakAlwaysOn, , 1;
""")
    truth = config.model_copy(deep=True)
    truth.source = config.source
    truth.model.idf_objects = [*config.model.idf_objects, hidden]
    fitted = extend_config(config, EXTENSIONS["infiltration"], tmp_path / "ext", output=OUTPUT,
                           terms=("D",))
    assert [p.name for p in fitted.parameters if p.group == "extension"] == [
        "infiltration_d_m3s_per_m2s2"]
    base = nominal(config)
    expected = simulate(truth, [base], tmp_path / "truth", "surrogate")[0]
    predicted = simulate(fitted, [{**base, "infiltration_d_m3s_per_m2s2": 0.004},
                                  {**base, "infiltration_d_m3s_per_m2s2": 0.0}],
                         tmp_path / "fit", "surrogate")
    np.testing.assert_allclose(predicted[0], expected, rtol=0, atol=1e-9)
    assert np.max(np.abs(predicted[1] - expected)) > 20.0     # the leak matters


def test_surrogate_internal_mass_stores_heat_and_keeps_the_balance(surrogate_base, tmp_path):
    """The mass's nodes join the network: energy balance closes, chain solve = dense solve."""
    from bpsflow.simulation.idf import model_objects
    from bpsflow.surrogate.cell import build_cell
    from bpsflow.surrogate.forcing import constant_forcing
    from bpsflow.surrogate.network import build_network
    from bpsflow.surrogate.network import simulate as step_network
    from bpsflow.surrogate.params import field_values, sample_columns

    config = extend_config(surrogate_base, EXTENSIONS["thermal_mass"], tmp_path, output=OUTPUT)
    samples = sample_columns(config, pd.DataFrame(index=pd.RangeIndex(2, name="instance")))
    samples["internal_mass_area_m2"] = [5.0, 80.0]
    samples["internal_mass_thickness_m"] = [0.1, 0.3]
    thick = build_cell(config, field_values(config, model_objects(config.model), samples))
    # the thickness is sampled per instance: half the slab behind each m2
    np.testing.assert_allclose([s for s in thick.opaque if s.kind == "internal_mass"][0]
                               .layers[0].thickness, [0.05, 0.15])
    samples["internal_mass_thickness_m"] = [0.1, 0.1]
    cell = build_cell(config, field_values(config, model_objects(config.model), samples))
    mass = [s for s in cell.opaque if s.kind == "internal_mass"]
    assert len(mass) == 1 and mass[0].adiabatic
    np.testing.assert_allclose(mass[0].area, [5.001, 80.001])
    # half of the 0.1 m slab behind each m2 (EnergyPlus: both faces see the zone)
    np.testing.assert_allclose(mass[0].layers[0].thickness, [0.05, 0.05])
    network = build_network(cell)
    # the cell cools from 23 °C towards 5 °C outdoors: the mass gives back its heat
    forcing = constant_forcing(cell, days=2, t_out=5.0, boundary_c=15.0, wind=2.0)
    fast = step_network(cell, network, forcing, max_warmup_days=0, account=True)
    dense = step_network(cell, network, forcing, max_warmup_days=0, dense=True)
    np.testing.assert_allclose(fast.state, dense.state, atol=1e-8)
    e = fast.energy
    inflow = e["hvac"] + e["solar"] + e["internal"] + e["ventilation"] + e["exterior"] \
        + e["boundary"]
    scale = np.abs(e["ventilation"]) + np.abs(e["exterior"]) + np.abs(e["boundary"])
    np.testing.assert_allclose(inflow, e["stored"], atol=1e-8 * scale.max())
    # 75 m2 more of 0.05 m concrete (1.89 MJ/(m3 K)) cooling by about the same drop
    extra = e["stored"][1] - e["stored"][0]
    drop = 23.0 - fast.state[1, network.inside[cell.opaque.index(mass[0])]]
    assert extra == pytest.approx(-75.0 * 0.05 * 2100 * 900 * drop, rel=0.25)
    assert fast.air[1, 6 * 12] > fast.air[0, 6 * 12] + 0.5     # the mass holds the air up


def test_surrogate_internal_mass_needs_a_symmetric_construction(surrogate_base, tmp_path):
    extended = extend_config(surrogate_base, EXTENSIONS["thermal_mass"], tmp_path / "ext",
                             output=OUTPUT)
    snippet = extended.model.idf_objects[-1]
    text = snippet.read_text()
    # a gypsum layer on the inside only: the two faces differ
    lines = [line if "!- Outside Layer" not in line else
             line.split(";")[0] + ",\n    InteriorGypsum;"
             for line in text.splitlines()]
    snippet.write_text("\n".join(lines))
    with pytest.raises(BpsflowError, match="is not symmetric"):
        simulate(extended, [nominal(extended)], tmp_path / "runs", "surrogate")


# ---------------------------------------------------------------------------
# Nested at zero on EnergyPlus


@pytest.mark.energyplus
@pytest.mark.slow
def test_new_extensions_are_nested_at_zero_on_energyplus(tmp_path):
    """The same nesting on EnergyPlus, and the surrogate's response to each parameter.

    Tolerance at 0: the infiltration and gain parameters leave EnergyPlus's
    equations unchanged (measured: identical output); the thermal mass keeps
    a token 0.001 m², and adding any surface perturbs EnergyPlus's inside
    heat balance slightly (measured: 0.26 W at most, 0.03 W on average, of a
    mean of 575 W; the same with 1e-5 m², 2 W with 0.1 m²).

    Each parameter then moves EnergyPlus's output as it moves the
    surrogate's (measured: infiltration terms and gain within 1 % in mean,
    hourly correlation ≥ 0.995; the mass's hourly response correlates 0.98,
    the surrogate's about 1.1 times as large).
    """
    config = base_config(tmp_path / "base", "energyplus")
    extended = all_extensions(config, tmp_path / "ext")
    zero = nested_point(config, extended)
    rows = [zero, {**zero, "scheduled_gain_radiant_fraction": 0.6}]
    rows += [{**zero, name: value} for name, value in INFILTRATION_TERMS.items()]
    rows += [{**zero, "scheduled_gain_w": 300.0, "scheduled_gain_radiant_fraction": 0.6},
             {**zero, "internal_mass_area_m2": 60.0},
             {**zero, "scheduled_air_flow_m3s": 0.05}]
    predicted = simulate(extended, rows, tmp_path / "runs", "energyplus")
    original = simulate(config, [nominal(config)], tmp_path / "runs0", "energyplus")[0]
    np.testing.assert_allclose(predicted[1], predicted[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(predicted[0], original, rtol=0, atol=0.5)
    assert np.mean(np.abs(predicted[0] - original)) < 0.1
    for row, name in zip(predicted[2:6], INFILTRATION_TERMS):
        assert np.mean(row - original) > 5.0, name
    radiant, mass = predicted[6], predicted[7]
    start_hour = (HOURS - pd.Timedelta(hours=1)).hour
    on = (start_hour >= 1) & (start_hour < 6)
    assert np.mean(radiant[on] - original[on]) < -100.0      # the gain reaches the zone
    assert (daily_swing(mass) < daily_swing(original)).all()
    # the surrogate has the same physics for every new field
    surrogate_config = extended.model_copy(deep=True)
    surrogate_config.source = extended.source
    surrogate_config.model.backend = "surrogate"
    surrogate = simulate(surrogate_config, rows, tmp_path / "surrogate", "surrogate")
    for j in (2, 3, 4, 5, 6, 8):        # infiltration terms, radiant gain, scheduled air
        on_energyplus, on_surrogate = predicted[j] - predicted[0], surrogate[j] - surrogate[0]
        assert np.mean(on_surrogate) == pytest.approx(np.mean(on_energyplus), rel=0.02)
        assert np.corrcoef(on_surrogate, on_energyplus)[0, 1] > 0.99
    on_energyplus, on_surrogate = predicted[7] - predicted[0], surrogate[7] - surrogate[0]
    assert np.corrcoef(on_surrogate, on_energyplus)[0, 1] > 0.95
    assert np.sqrt(np.mean(on_surrogate ** 2)) / np.sqrt(np.mean(on_energyplus ** 2)) \
        == pytest.approx(1.0, abs=0.25)


def test_gain_blocks_ignore_hours_at_which_the_output_cannot_respond():
    """A heating power that is zero (the zone floats) hides a gain; those hours carry no weight.

    An all-days 10-18 h gain shows in the heating residual only on the days the
    heating runs at midday; on the others heating is zero in model and data,
    and the residual is zero whatever the gain. Masked to the responsive
    hours, the screen finds the all-days block and its level; every block
    listed has a positive level (a gain cannot be negative).
    """
    rng = np.random.default_rng(11)
    hours = pd.date_range("2025-11-03 01:00", periods=24 * 28, freq="h")
    start = hours - pd.Timedelta(hours=1)
    hour = np.asarray(start.hour)
    block = (hour >= 10) & (hour < 18)
    # heating runs at midday on a few dull days only, at random: on the rest it is off
    dull_day = rng.random(28) < 0.3
    responsive = ~block | dull_day[np.arange(len(hours)) // 24]
    residual = np.where(responsive, -90.0 * block + rng.normal(0, 8.0, len(hours)), 0.0)
    # the morning reheat after a gain-warmed day is lower: a negative block the screen skips
    residual += 25.0 * ((hour >= 5) & (hour < 8))
    blocks = gain_blocks(pd.Series(residual, index=hours), -1.0, count=3, responsive=responsive)
    first = blocks[0][1]
    assert (first["day_type"], first["start_hour"], first["end_hour"]) == ("all days", 10, 18)
    assert first["level"] == pytest.approx(90.0, rel=0.1)
    assert all(b["level"] > 0 for _, b in blocks)
    # unmasked, the zero hours count against an every-day block: a single weekday whose
    # middays happened to be dull wins instead
    unmasked = gain_blocks(pd.Series(residual, index=hours), -1.0, count=3)
    assert unmasked[0][1]["day_type"] != "all days"


def test_the_console_table_names_each_extension_by_its_cause_and_face():
    """Two apertures tried in one round must be told apart (before, both read
    '+ solar_aperture')."""
    from types import SimpleNamespace

    from rich.console import Console

    from bpsflow.diagnosis.command import summary_table

    scores = {"cvrmse": 0.05, "nmcrps": 0.03, "nmbe": 0.0}
    result = SimpleNamespace(
        output="heating_power_w", verdict="model_form", parameter_fit=None,
        scorecard={"heldout": scores},
        extensions=[{"name": "solar_aperture", "cause": f"solar_aperture ({face})", "round": 1,
                     "fitted": {"solar_aperture_m2": 0.5}, "heldout": {"after": scores},
                     "accepted": face == "west"} for face in ("west", "north")])
    console = Console(width=200, record=True)
    console.print(summary_table(result))
    text = console.export_text()
    assert "+ solar_aperture (west) (round 1)" in text
    assert "+ solar_aperture (north) (round 1)" in text


def test_an_aperture_on_a_face_the_zone_lacks_is_labelled_as_such():
    """A west aperture of a zone with interior walls east and west read as a west facade."""
    from bpsflow.diagnosis.report import _extension_label

    own = {"name": "solar_aperture", "cause": "solar_aperture (south)", "zone": "EXAM",
           "facade": "south", "surfaces": ["EXAM South Wall"]}
    lacking = {**own, "cause": "solar_aperture (west)", "facade": "west", "surfaces": []}
    assert "south facade: EXAM South Wall" in _extension_label(own)
    assert "the zone has no outdoor surface facing west" in _extension_label(lacking)
