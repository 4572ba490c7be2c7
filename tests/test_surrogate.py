"""The bundled surrogate: physics checks of the RC network and the backend plumbing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bpsflow.boundary import ensure_sequences
from bpsflow.config import load_config
from bpsflow.diagnosis.extensions import EXTENSIONS, extend_config, year_hours
from bpsflow.simulation.idf import model_objects, polygon_area, read_idf
from bpsflow.surrogate.cell import build_cell
from bpsflow.surrogate.forcing import constant_forcing, period_forcing
from bpsflow.surrogate.network import build_network, simulate
from bpsflow.surrogate.params import field_values, sample_columns
from bpsflow.surrogate.run import ignored_targets, simulate_instances
from bpsflow.surrogate.solar import double_glazing

from conftest import ROOT, short_raw, write_config

IDF = ROOT / "sample_idf" / "flexlab_x3b.idf"


def nominal_cell(config, ventilation: bool = True, n: int = 1):
    samples = sample_columns(config, pd.DataFrame(index=pd.RangeIndex(n, name="instance")))
    cell = build_cell(config, field_values(config, read_idf(config.model.idf), samples))
    if not ventilation:
        cell.ventilation_m3s = np.zeros(n)
    return cell


@pytest.fixture
def config(tmp_path: Path):
    return load_config(write_config(tmp_path, short_raw()))


def test_idf_reader_geometry_and_fields():
    idf = read_idf(IDF)
    window = idf.find("FenestrationSurface:Detailed", "SouthWindow")
    assert polygon_area(window.vertices()) == pytest.approx(6.0, rel=1e-6)
    floor = idf.find("BuildingSurface:Detailed", "Floor")
    assert polygon_area(floor.vertices()) == pytest.approx(9.144 * 6.096, rel=1e-6)
    assert idf.find("Material", "SuperInsulation").number("Thickness") == 0.56
    assert idf.find("WindowMaterial:Glazing", "ClearGlass3mm").number(
        "Solar Transmittance at Normal Incidence") == 0.837


def test_cell_lumps_like_boundary_walls(config):
    cell = nominal_cell(config)
    names = sorted(s.name for s in cell.opaque)
    assert "EastWall+NorthWall+WestWall" in names
    south = next(s for s in cell.opaque if s.outdoor)
    assert south.area == pytest.approx(9.144 * 3.658 - 6.0, rel=1e-6)
    walls = next(s for s in cell.opaque if "+" in s.name)
    assert sum(walls.boundary_weights.values()) == pytest.approx(1.0)
    assert walls.boundary_weights["north"] == pytest.approx(9.144 / (9.144 + 2 * 6.096))


def test_glazing_optics_reproduce_normal_incidence_and_fall_off():
    g = double_glazing(np.array([0.837]), np.array([0.075]), np.array([0.075]), np.array([1.0]))
    t1, r1 = 0.837, 0.075
    # Two panes with inter-reflection at normal incidence.
    assert g.transmittance[0, 0] == pytest.approx(t1 * t1 / (1 - r1 * r1), rel=1e-3)
    assert np.all(np.diff(g.transmittance[0]) <= 1e-12)        # falls with angle
    assert g.transmittance[0, -1] == 0.0
    assert 0.5 < g.diffuse_transmittance[0] < g.transmittance[0, 0]


def test_energy_balance_closes(config):
    """Heat in (HVAC, sun) = heat stored + heat out, over a real run period with control."""
    samples = sample_columns(config, pd.DataFrame(index=pd.RangeIndex(3, name="instance")))
    samples["ground_reflectance"] = [0.1, 0.25, 0.4]
    cell = build_cell(config, field_values(config, read_idf(config.model.idf), samples))
    from bpsflow.surrogate.forcing import period_forcing

    run_dir = config.run_dir.resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    from bpsflow.boundary import draw_sequences, period_hours, write_sequences

    write_sequences(draw_sequences(config.model.boundary, period_hours(config)), run_dir)
    forcing = period_forcing(config, cell, config.model.periods[0], samples, run_dir)
    result = simulate(cell, build_network(cell), forcing, account=True)
    e = result.energy
    inflow = e["hvac"] + e["solar"] + e["ventilation"] + e["exterior"] + e["boundary"]
    scale = np.abs(e["hvac"]) + e["solar"] + np.abs(e["ventilation"]) + np.abs(e["exterior"])
    assert np.all(e["solar"] > 0) and np.all(e["hvac"] > 0)
    np.testing.assert_allclose(inflow, e["stored"], atol=1e-8 * scale.max())
    # Storage over a few days is small against the throughput.
    assert np.all(np.abs(e["stored"]) < 0.2 * scale)


def test_steady_conduction_matches_u_a_delta_t(config):
    cell = nominal_cell(config, ventilation=False)
    network = build_network(cell)
    forcing = constant_forcing(cell, days=12, t_out=0.0, boundary_c=20.0,
                               heating_c=25.0, cooling_c=25.0)
    result = simulate(cell, network, forcing, max_warmup_days=0)
    state = result.state[0]
    for i, surface in enumerate(cell.opaque):
        resistance = sum(float(layer.thickness[0] / layer.conductivity[0])
                         for layer in surface.layers)
        inside = state[network.inside[i]]
        outside = state[network.outside[i]] if surface.outdoor else 20.0
        expected = surface.area / resistance * (inside - outside)       # W, room -> out
        # Flux through the outermost element of the wall at steady state.
        if surface.outdoor:
            first, second = network.outside[i], network.outside[i] + 1
            g = _element_conductance(network, first, second)
            flux = g * (state[second] - state[first])
        else:
            node = network.boundary_node[i]
            flux = network.boundary_g[i][0] * (state[node] - 20.0)
        assert abs(inside - outside) > 1.0
        assert flux == pytest.approx(expected, rel=1e-3)
    # Holding 25 °C against 0 °C outside and 20 °C around takes heat.
    assert result.power[0, -1] > 0


def _element_conductance(network, i, j):
    size = network.size
    return -network.static[0, i * size + j]


def test_free_floating_cell_without_gains_relaxes_to_boundary(config):
    cell = nominal_cell(config, ventilation=False)
    # An imposed vertical gradient offsets the mean air from the surfaces (the
    # pattern is not mixed air); without it everything settles at the boundary.
    cell.gradient = np.zeros(cell.n)
    forcing = constant_forcing(cell, days=30, t_out=15.0, boundary_c=15.0)
    result = simulate(cell, build_network(cell), forcing, max_warmup_days=0)
    assert np.all(result.power == 0.0)
    assert result.air[0, 0] > 20.0                     # starts at 23 °C
    assert result.air[0, -1] == pytest.approx(15.0, abs=0.05)
    np.testing.assert_allclose(result.state[0], 15.0, atol=0.1)


def test_free_floating_cell_settles_between_boundaries(config):
    """Warm guarded spaces, cold outside: the cell settles in between, nearer the guards."""
    cell = nominal_cell(config, ventilation=False)
    forcing = constant_forcing(cell, days=30, t_out=0.0, boundary_c=20.0)
    air = simulate(cell, build_network(cell), forcing, max_warmup_days=0).air[0, -1]
    assert 10.0 < air < 20.0


def _two_day_config(tmp_path, summer: bool):
    raw = short_raw()
    if summer:
        raw["model"]["periods"] = [{"name": "summer", "start": "07-05", "end": "07-08"}]
        raw["model"]["tests"] = [
            {"name": "C-CT", "period": "summer", "start": "07-05", "days": 2, "warmup_days": 1,
             "mode": "cooling", "setpoint_c": 20.0, "outputs": ["cooling_power_w"]},
            {"name": "C-FF", "period": "summer", "start": "07-07", "days": 2, "warmup_days": 1,
             "mode": "free_floating", "outputs": ["zone_air_temperature_c"]}]
    raw["parameters"] = [p for p in raw["parameters"] if p["distribution"]["type"] != "sampler"]
    tmp_path.mkdir(parents=True, exist_ok=True)
    return load_config(write_config(tmp_path, raw))


def _means(config, samples):
    tidy, _ = simulate_instances(config, samples)
    return tidy.groupby(["test", "instance"])["value"].mean().unstack("test")


@pytest.mark.parametrize("parameter, low, high", [
    ("glazing_solar_transmittance", 0.98, 1.02),
    ("ground_reflectance", 0.1, 0.4),
])
def test_outputs_respond_to_solar_inputs_with_the_right_sign(tmp_path, parameter, low, high):
    summer = _two_day_config(tmp_path / "s", summer=True)
    winter = _two_day_config(tmp_path / "w", summer=False)
    for config, more_sun_raises, lowers in ((summer, ["C-CT", "C-FF"], []),
                                            (winter, ["H-FF"], ["H-ST"])):
        samples = pd.DataFrame({parameter: [low, high]},
                               index=pd.RangeIndex(2, name="instance"))
        means = _means(config, samples)
        for test in more_sun_raises:
            assert means.loc[1, test] > means.loc[0, test], (parameter, test)
        for test in lowers:
            assert means.loc[1, test] < means.loc[0, test], (parameter, test)


def test_heating_grows_with_the_setpoint(tmp_path):
    results = []
    for setpoint in (25.0, 30.0):
        config = _two_day_config(tmp_path / str(setpoint), summer=False)
        config.model.tests[0].setpoint_c = setpoint
        results.append(_means(config, pd.DataFrame(index=pd.RangeIndex(1, name="instance"))))
    assert results[1].loc[0, "H-ST"] > results[0].loc[0, "H-ST"] > 0
    assert results[1].loc[0, "H-FF"] == pytest.approx(results[0].loc[0, "H-FF"], abs=0.5)


def test_outputs_follow_the_test_windows(tmp_path):
    config = _two_day_config(tmp_path, summer=False)
    tidy, _ = simulate_instances(config, pd.DataFrame(index=pd.Index(["truth"], name="instance")))
    h_st = tidy[tidy.test == "H-ST"]
    assert list(tidy.columns) == ["instance", "test", "output", "timestamp", "value"]
    assert len(h_st) == 48 and (tidy.instance == "truth").all()
    assert h_st.timestamp.min() == pd.Timestamp("2025-12-05 01:00")
    assert h_st.timestamp.max() == pd.Timestamp("2025-12-07 00:00")
    assert (tidy.value.notna()).all()


def test_ignored_targets_are_named(config):
    ignored = " ".join(ignored_targets(config))
    assert "Visible Transmittance" in ignored and "glazing_visible_transmittance" in ignored
    assert "wind_direction" in ignored
    assert "glazing_solar_transmittance" not in ignored
    assert "ground_reflectance" not in ignored


def test_auto_backend_falls_back_and_runs(tmp_path, monkeypatch):
    import bpsflow.simulation.energyplus as energyplus_backend
    from bpsflow.boundary import draw_sequences, period_hours, write_sequences
    from bpsflow.sampling import sample, write_design
    from bpsflow.simulation.backend import choose_backend
    from bpsflow.simulation.ensemble import run_ensemble

    raw = short_raw(samples=4)
    raw["model"]["backend"] = "auto"
    config = load_config(write_config(tmp_path, raw))
    monkeypatch.setattr(energyplus_backend, "find_energyplus", lambda override=None: None)
    messages: list[str] = []
    chosen = choose_backend(config, announce=messages.append)
    assert chosen.name == "surrogate"
    assert any("falling back" in m and "surrogate" in m for m in messages)

    run_dir = config.run_dir.resolve()
    design = sample(config)
    write_design(design, run_dir)
    write_sequences(draw_sequences(config.model.boundary, period_hours(config)), run_dir)
    summary = run_ensemble(config, design.values, chosen, show_progress=False)
    assert summary.backend == "surrogate" and summary.ok == 4 and summary.failed == 0
    results = pd.read_parquet(run_dir / "results.parquet")
    manifest = pd.read_parquet(run_dir / "manifest.parquet")
    assert sorted(results.instance.unique()) == [0, 1, 2, 3]
    assert set(manifest.backend) == {"surrogate"} and set(manifest.status) == {"ok"}
    assert results.groupby(["instance", "test"]).size().eq(48).all()


def test_chain_elimination_equals_dense_solve(config):
    samples = sample_columns(config, pd.DataFrame(index=pd.RangeIndex(2, name="instance")))
    samples["glazing_dirt_correction"] = [0.75, 1.0]
    cell = build_cell(config, field_values(config, read_idf(config.model.idf), samples))
    network = build_network(cell)
    forcing = constant_forcing(cell, days=2, t_out=5.0, boundary_c={1: 22.0, 2: 24.0, 3: 30.0},
                               heating_c=28.0, cooling_c=40.0, wind=3.0, t_sky=-5.0)
    fast = simulate(cell, network, forcing, max_warmup_days=0)
    dense = simulate(cell, network, forcing, max_warmup_days=0, dense=True)
    np.testing.assert_allclose(fast.state, dense.state, atol=1e-8)
    np.testing.assert_allclose(fast.power, dense.power, rtol=1e-8, atol=1e-6)


def test_synthetic_measurements_on_the_surrogate(tmp_path):
    from bpsflow.measured import read_measured
    from bpsflow.synth import Truth, synthesize

    config = _two_day_config(tmp_path, summer=False)
    path = synthesize(config, Truth(values={"ground_reflectance": 0.3}, seed=3), tmp_path / "syn",
                      backend="surrogate")
    measured = read_measured(path, config).frame
    assert len(measured) == 96
    assert set(measured.columns) >= {"heating_power_w", "zone_air_temperature_c"}
    assert measured["zone_air_temperature_c"].between(-10, 60).all()


def test_truth_json_records_the_noise_added_to_every_output_defaults_included(tmp_path):
    """A truth file without ``noise`` still gets the unit's default noise: the record says so."""
    import json

    from bpsflow.synth import TRUTH_FILE, Noise, Truth, default_noise, synthesize

    config = _two_day_config(tmp_path, summer=False)
    own = Noise(kind="absolute", bound=0.3)
    synthesize(config, Truth(values={}, seed=3, noise={"zone_air_temperature_c": own}),
               tmp_path / "syn", backend="surrogate")
    record = json.loads((tmp_path / "syn" / TRUTH_FILE).read_text())
    assert record["noise"]["zone_air_temperature_c"] == own.model_dump()
    heating_unit = config.outputs["heating_power_w"].unit
    assert record["noise"]["heating_power_w"] == default_noise(heating_unit).model_dump()
    assert "heating_power_w" in record["noise_defaulted"]
    assert "zone_air_temperature_c" not in record["noise_defaulted"]


# Detailed quantities (EnergyPlus output variables by surface and site) -----------

INSIDE = "Surface Inside Face "
BALANCE = ("Convection Heat Gain Rate per Area", "Conduction Heat Transfer Rate per Area",
           "Net Surface Thermal Radiation Heat Gain Rate per Area",
           "Solar Radiation Heat Gain Rate per Area")
OPAQUE = ("EastWall", "NorthWall", "WestWall", "Ceiling", "Floor", "SouthWall")


def _with_outputs(config, wanted: dict[str, tuple[str, str]]):
    """The config with extra outputs ``name -> (variable, key)`` asked for by every test."""
    from bpsflow.config import OutputVariable

    for name, (variable, key) in wanted.items():
        config.outputs[name] = OutputVariable(variable=variable, key=key)
    for test in config.model.tests:
        test.outputs = sorted(set(test.outputs) | set(wanted))
    return config


def _wide(tidy: pd.DataFrame) -> pd.DataFrame:
    return (tidy.drop_duplicates(["instance", "timestamp", "output"])
            .pivot(index=["instance", "timestamp"], columns="output", values="value"))


def _probe_run(config, forcing_of, wanted_terms, n: int = 1):
    from bpsflow.surrogate.network import FaceProbe

    cell = nominal_cell(config, n=n)
    forcing = forcing_of(cell)
    faces = len(cell.opaque) + 1
    probe = FaceProbe({m: set(wanted_terms) for m in range(faces)}, forcing.days * 24,
                      forcing.steps_per_hour)
    result = simulate(cell, build_network(cell), forcing, probe=probe)
    return cell, probe, result


def test_inside_face_balance_closes_at_every_face(tmp_path):
    """Convection + conduction + net long-wave + solar = 0 at each inside face (seed eq. 15)."""
    from bpsflow.surrogate.forcing import period_forcing
    from bpsflow.surrogate.network import FACE_TERMS

    config = _two_day_config(tmp_path, summer=True)
    config = _with_outputs(config, {f"{s}:{t}": (INSIDE + t, s.upper() if s == "Floor" else s)
                                    for s in OPAQUE for t in BALANCE})
    samples = pd.DataFrame({"ground_reflectance": [0.1, 0.4]},
                           index=pd.RangeIndex(2, name="instance"))
    wide = _wide(simulate_instances(config, samples)[0])
    for surface in OPAQUE:
        terms = wide[[f"{surface}:{t}" for t in BALANCE]]
        scale = terms.abs().to_numpy().max()
        assert scale > 1.0, surface                          # the faces do exchange heat
        np.testing.assert_allclose(terms.sum(axis=1), 0.0, atol=1e-9 * scale, err_msg=surface)
        # The sun reaches every inside face and nothing is absorbed at night.
        solar = terms[f"{surface}:{BALANCE[3]}"]
        assert solar.max() > 0.5 and solar.min() >= 0.0
    # The window's room-side pane too (its conduction is the flow across the gap).
    _, probe, _ = _probe_run(config, lambda cell: period_forcing(
        config, cell, config.model.periods[0], sample_columns(
            config, pd.DataFrame(index=pd.RangeIndex(1, name="instance")))), FACE_TERMS)
    window = len(probe.wanted) - 1
    terms = [probe.values[(window, t)] for t in ("convection", "conduction", "radiation", "solar")]
    scale = max(np.abs(t).max() for t in terms)
    assert scale > 10.0
    np.testing.assert_allclose(sum(terms), 0.0, atol=1e-9 * scale)


def test_convection_coefficient_is_the_curve_at_the_face_temperature_difference(config):
    """At a steady state, h = alpha |T_adjacent - T_face|^n (seed eqs. 16-17) at every face."""
    from bpsflow.surrogate.network import H_MIN

    boundary = {1: 30.0, 2: 26.0, 3: 14.0}      # guarded spaces warmer and colder than the cell
    cell, probe, _ = _probe_run(config, lambda cell: constant_forcing(
        cell, days=20, t_out=0.0, boundary_c=boundary, wind=2.0),
        ("temperature", "adjacent_air", "convection_coefficient", "convection"))
    assert cell.gradient[0] > 0.5
    for m, curve in enumerate([s.inside_curve for s in cell.opaque] + [cell.window.inside_curve]):
        t_face = probe.values[(m, "temperature")][0, -1]
        t_adjacent = probe.values[(m, "adjacent_air")][0, -1]
        h = probe.values[(m, "convection_coefficient")][0, -1]
        difference = abs(t_adjacent - t_face)
        assert difference > 0.05, m
        expected = max(float(curve.c1[0] + curve.c2[0] * difference ** curve.c3[0]), H_MIN)
        assert h == pytest.approx(expected, rel=1e-6), m
        assert probe.values[(m, "convection")][0, -1] == pytest.approx(
            h * (t_adjacent - t_face), rel=1e-6)


def test_adjacent_air_follows_the_sampled_gradient(tmp_path):
    """(T_ceiling air - T_floor air) / (centroid height difference) = gradient x 0.98.

    EnergyPlus's ConstantGradient pattern places a surface at its centroid's
    non-dimensional height bounded to 0.01..0.99 of the zone height, so the
    floor and ceiling air lie 0.98 H apart in the pattern, not H (seed eq. 18
    read on EnergyPlus output gives 0.98 x the gradient).
    """
    from bpsflow.surrogate.cell import ZETA_BOUNDS

    config = _two_day_config(tmp_path, summer=False)
    config = _with_outputs(config, {
        "ceiling_air": (INSIDE + "Adjacent Air Temperature", "ceiling"),   # keys: any case
        "floor_air": (INSIDE + "Adjacent Air Temperature", "FLOOR"),
        "wall_air": (INSIDE + "Adjacent Air Temperature", "NorthWall"),
        "mean_air": ("Zone Mean Air Temperature", "Cell")})
    gradients = [0.5, 1.4, 1.875]
    samples = pd.DataFrame({"stratification_gradient": gradients},
                           index=pd.RangeIndex(3, name="instance"))
    wide = _wide(simulate_instances(config, samples)[0])
    idf = read_idf(config.model.idf)
    ceiling = idf.find("BuildingSurface:Detailed", "Ceiling").vertices()
    floor = idf.find("BuildingSurface:Detailed", "Floor").vertices()
    rise = np.mean([v[2] for v in ceiling]) - np.mean([v[2] for v in floor])
    share = ZETA_BOUNDS[1] - ZETA_BOUNDS[0]
    assert share == pytest.approx(0.98)
    for instance, gradient in enumerate(gradients):
        rows = wide.loc[instance]
        estimate = (rows["ceiling_air"] - rows["floor_air"]) / rise
        np.testing.assert_allclose(estimate, gradient * share, rtol=1e-9)
        # Mid-height walls sit in the mean air.
        np.testing.assert_allclose(rows["wall_air"], rows["mean_air"], atol=1e-9)


def test_solar_quantities_of_the_site_and_the_facade(tmp_path):
    """Ground-diffuse on a vertical facade = 0.5 rho GHI; window transmits 0 < tau < tau_n."""
    config = _two_day_config(tmp_path, summer=True)
    config = _with_outputs(config, {
        "ground_wall": ("Surface Outside Face Incident Ground Diffuse Solar Radiation Rate per "
                        "Area", "SouthWall"),
        "ground_window": ("Surface Outside Face Incident Ground Diffuse Solar Radiation Rate "
                          "per Area", "SouthWindow"),
        "reflected": ("Site Ground Reflected Solar Radiation Rate per Area", "Environment"),
        "direct": ("Site Direct Solar Radiation Rate per Area", "environment"),
        "diffuse": ("Site Diffuse Solar Radiation Rate per Area", "Environment"),
        "altitude": ("Site Solar Altitude Angle", "Environment"),
        "incident": ("Surface Outside Face Incident Solar Radiation Rate per Area",
                     "SouthWindow"),
        "transmitted": ("Surface Window Transmitted Solar Radiation Rate", "SouthWindow")})
    reflectances = [0.1, 0.35]
    samples = pd.DataFrame({"ground_reflectance": reflectances, "glazing_dirt_correction": 1.0},
                           index=pd.RangeIndex(2, name="instance"))
    wide = _wide(simulate_instances(config, samples)[0])
    global_horizontal = [wide.loc[i, "reflected"] / rho for i, rho in enumerate(reflectances)]
    np.testing.assert_allclose(global_horizontal[0], global_horizontal[1], rtol=1e-12)
    ghi = global_horizontal[0]
    for i, rho in enumerate(reflectances):
        for face in ("ground_wall", "ground_window"):
            np.testing.assert_allclose(wide.loc[i, face], 0.5 * rho * ghi, rtol=1e-12)
    rows = wide.loc[0]
    assert ghi.max() > 500.0                                   # a sunny July day
    # Global horizontal lies between the diffuse part and diffuse + normal beam.
    assert (ghi >= rows["diffuse"] - 1e-9).all() and (ghi <= rows["diffuse"] + rows["direct"]
                                                      + 1e-9).all()
    night = rows["altitude"] < -10.0
    assert night.sum() > 10 and (rows.loc[night, ["direct", "diffuse", "reflected", "incident",
                                                  "transmitted"]] == 0.0).all().all()
    # Transmitted / incident of the window: below the normal-incidence transmittance.
    glass = read_idf(config.model.idf).find("WindowMaterial:Glazing", "ClearGlass3mm")
    tau = glass.number("Solar Transmittance at Normal Incidence")
    rho_glass = glass.number("Front Side Solar Reflectance at Normal Incidence")
    normal = tau * tau / (1 - rho_glass * rho_glass)           # two panes, inter-reflected
    sunny = rows["incident"] > 100.0
    ratio = rows.loc[sunny, "transmitted"] / (rows.loc[sunny, "incident"] * 6.0)
    assert sunny.sum() > 8
    assert (ratio > 0.0).all() and (ratio < normal).all()
    assert ratio.max() > 0.5 * normal


def test_sun_position_is_energyplus_s(tmp_path):
    """Hourly solar altitude as EnergyPlus 25.2 reports it at the San Francisco TMY3 site."""
    from bpsflow.surrogate.solar import sun_positions

    # Hour-ending means of the 10-minute values, from an EnergyPlus 25.2 run.
    reference = {"2025-07-09 07:00": 17.3878, "2025-07-09 13:00": 73.8148,
                 "2025-07-21 18:00": 20.2752, "2025-12-15 09:00": 11.6984,
                 "2025-12-15 13:00": 28.5662, "2025-12-22 00:00": -73.931}
    for first, days in (("2025-07-05", 18), ("2025-12-05", 18)):
        ends = pd.Timestamp(first) + pd.to_timedelta(np.arange(1, days * 144 + 1) * 10,
                                                     unit="min")
        zenith, azimuth, beam_zenith, _ = sun_positions(pd.DatetimeIndex(ends), 37.62, -122.40,
                                                        -8.0)
        altitude = pd.Series(90.0 - zenith, index=ends)
        hourly = altitude.groupby(np.arange(len(ends)) // 6).mean()
        hourly.index = ends[5::6]
        for stamp, value in reference.items():
            if pd.Timestamp(stamp) in hourly.index:
                assert hourly[pd.Timestamp(stamp)] == pytest.approx(value, abs=2e-3), stamp
        # Morning sun in the east, afternoon in the west.
        noon = ends.hour == 12
        assert np.all(azimuth[(ends.hour == 9) & (zenith < 90)] < 180)
        assert np.all(azimuth[(ends.hour == 15) & (zenith < 90)] > 180)
        # The beam's sun uses the period's mean declination: in July the real
        # sun sinks through the period, so it stands lower than the mean first.
        if first.startswith("2025-07"):
            first_day, last_day = noon & (ends.day == 5), noon & (ends.day == 22)
            assert np.all(zenith[first_day] < beam_zenith[first_day])
            assert np.all(zenith[last_day] > beam_zenith[last_day])
        one_day = sun_positions(pd.DatetimeIndex(ends), 37.62, -122.40, -8.0, shading_days=1)
        np.testing.assert_allclose(one_day[2], zenith, atol=1e-9)


def test_detailed_outputs_name_bad_variables_and_keys(tmp_path):
    from bpsflow.errors import BpsflowError

    base = _two_day_config(tmp_path, summer=False)
    cases = [
        ({"bad_key": (INSIDE + "Temperature", "EastWal")},
         ["outputs.bad_key.key", "'EastWal'", "EastWall", "Ceiling", "SouthWindow"]),
        ({"window_conduction": (INSIDE + BALANCE[1], "SouthWindow")},
         ["outputs.window_conduction.key", "does not report it for windows", "Floor"]),
        ({"site_on_a_wall": ("Site Direct Solar Radiation Rate per Area", "SouthWall")},
         ["outputs.site_on_a_wall.key", "Environment"]),
        ({"dark_face": ("Surface Outside Face Incident Solar Radiation Rate per Area", "Floor")},
         ["outputs.dark_face.key", "sun-exposed", "SouthWall", "SouthWindow"]),
        ({"zone_key": ("Zone Mean Air Temperature", "Room")}, ["outputs.zone_key.key", "Cell"]),
        ({"unknown": ("Surface Inside Face Beam Radiation Rate", "Floor")},
         ["outputs.unknown", "Surface Inside Face Beam Radiation Rate",
          "Surface Inside Face Temperature", "Site Solar Altitude Angle"]),
    ]
    for outputs, expected in cases:
        config = _with_outputs(base.model_copy(deep=True), outputs)
        with pytest.raises(BpsflowError) as error:
            simulate_instances(config, pd.DataFrame(index=pd.RangeIndex(1, name="instance")))
        for text in expected:
            assert text in str(error.value), (outputs, str(error.value))


def test_lumped_walls_report_the_same_values(tmp_path):
    config = _with_outputs(_two_day_config(tmp_path, summer=False), {
        f"{wall}_temperature": (INSIDE + "Temperature", wall)
        for wall in ("EastWall", "westwall", "NORTHWALL", "SouthWall")})
    wide = _wide(simulate_instances(config, pd.DataFrame(index=pd.RangeIndex(1,
                                                                             name="instance")))[0])
    np.testing.assert_array_equal(wide["EastWall_temperature"], wide["westwall_temperature"])
    np.testing.assert_array_equal(wide["EastWall_temperature"], wide["NORTHWALL_temperature"])
    assert (wide["EastWall_temperature"] - wide["SouthWall_temperature"]).abs().max() > 0.1


def test_compiled_step_equals_the_numpy_step_with_every_kind_of_term(tmp_path):
    """The compiled day loop (bpsflow.surrogate.kernel) against the numpy step it replaces.

    The model carries every term the step has: scheduled air exchanges of the
    full A + B|ΔT| + C·V + D·V² law, a scheduled gain with a radiant part, an
    internal mass (an adiabatic chain), a solar aperture, the glazing gap and
    a night setback (both setpoints acting), over a warm-up and several days.
    """
    raw = {"extends": str(ROOT / "configs" / "diagnosis.yaml"),
           "model": {"backend": "surrogate",
                     "periods": [{"name": "p", "start": "01-10", "end": "01-15"}],
                     "tests": [{"name": "T", "period": "p", "start": "01-10", "days": 6,
                                "warmup_days": 1, "mode": "heating", "setpoint_c": 28.0,
                                "setback_c": 18.0, "setback_start_hour": 18,
                                "setback_end_hour": 7, "outputs": ["heating_power_w"]}]}}
    config = load_config(write_config(tmp_path, raw))
    hours = year_hours(config.model.year)
    start_hour = (hours - pd.Timedelta(hours=1)).hour
    office = pd.Series(((start_hour >= 9) & (start_hour < 17)).astype(float), index=hours)
    irradiance = pd.Series(np.clip(np.sin((start_hour - 6) / 12 * np.pi), 0, None) * 400,
                           index=hours)
    for name, schedule in (("infiltration", None), ("internal_gain_schedule", office),
                           ("thermal_mass", None), ("solar_aperture", irradiance)):
        config = extend_config(config, EXTENSIONS[name], tmp_path / name, schedule)
    rows = [{p.name: float(p.distribution.nominal) for p in config.parameters}
            for _ in range(3)]
    extension_values = {"infiltration_a_m3s": 0.004, "infiltration_b_m3s_per_k": 0.0003,
                        "infiltration_c_m3s_per_ms": 0.002, "infiltration_d_m3s_per_m2s2": 0.0005,
                        "scheduled_gain_w": 400.0, "scheduled_gain_radiant_fraction": 0.5,
                        "internal_mass_area_m2": 20.0, "internal_mass_thickness_m": 0.15,
                        "solar_aperture_m2": 1.0}
    for scale, row in zip((0.5, 1.0, 2.0), rows):
        row.update({key: value * scale for key, value in extension_values.items()})
    samples = sample_columns(config, pd.DataFrame(rows, index=pd.RangeIndex(3, name="instance")))
    cell = build_cell(config, field_values(config, model_objects(config.model), samples))
    assert cell.air_exchanges and cell.internal_gains
    assert any(s.adiabatic for s in cell.opaque)
    ensure_sequences(config)
    network = build_network(cell)
    forcing = period_forcing(config, cell, config.model.periods[0], samples, tmp_path / "run")
    compiled = simulate(cell, network, forcing, compiled=True)
    reference = simulate(cell, network, forcing, compiled=False)
    assert compiled.warmup_days == reference.warmup_days
    assert np.ptp(reference.power) > 100.0 and (reference.power == 0).any()
    np.testing.assert_allclose(compiled.air, reference.air, rtol=0, atol=1e-9)
    np.testing.assert_allclose(compiled.power, reference.power, rtol=1e-9, atol=1e-7)
    np.testing.assert_allclose(compiled.state, reference.state, rtol=0, atol=1e-9)

