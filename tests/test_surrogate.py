"""The bundled surrogate: physics checks of the RC network and the backend plumbing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bpsflow.config import load_config
from bpsflow.surrogate import ignored_targets, simulate_instances
from bpsflow.surrogate.cell import build_cell
from bpsflow.surrogate.forcing import constant_forcing
from bpsflow.surrogate.idf import polygon_area, read_idf
from bpsflow.surrogate.network import build_network, simulate
from bpsflow.surrogate.params import field_values, sample_columns
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
    import bpsflow.runner as runner
    from bpsflow.boundary import draw_sequences, period_hours, write_sequences
    from bpsflow.sampling import sample, write_design

    raw = short_raw(samples=4)
    raw["model"]["backend"] = "auto"
    config = load_config(write_config(tmp_path, raw))
    monkeypatch.setattr(runner, "find_energyplus", lambda override=None: None)
    messages: list[str] = []
    assert runner.choose_backend(config, announce=messages.append) == "surrogate"
    assert any("falling back" in m and "surrogate" in m for m in messages)

    run_dir = config.run_dir.resolve()
    design = sample(config)
    write_design(design, run_dir)
    write_sequences(draw_sequences(config.model.boundary, period_hours(config)), run_dir)
    summary = runner.run(config, design.values, show_progress=False)
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
    from bpsflow.synth import Truth, read_measured, synthesize

    config = _two_day_config(tmp_path, summer=False)
    path = synthesize(config, Truth(values={"ground_reflectance": 0.3}, seed=3), tmp_path / "syn",
                      backend="surrogate")
    measured = read_measured(path)
    assert len(measured) == 96
    assert set(measured.columns) >= {"heating_power_w", "zone_air_temperature_c"}
    assert measured["zone_air_temperature_c"].between(-10, 60).all()
