"""Real EnergyPlus: instances carry the sampled values, runs produce outputs, failures stay isolated, resume works."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from bpsflow.cli import app
from bpsflow.config import load_config
from bpsflow.sampling import read_samples
from bpsflow.simulation.backend import get_backend
from bpsflow.simulation.energyplus.engine import find_energyplus, idd_path
from bpsflow.simulation.energyplus.instances import open_idf, write_instance
from bpsflow.simulation.ensemble import run_ensemble
from bpsflow.simulation.rundir import read_manifest, read_results

from conftest import short_raw, write_config

pytestmark = pytest.mark.energyplus
runner = CliRunner()


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """Three instances of the short case, run once for the module through the CLI."""
    folder = tmp_path_factory.mktemp("short")
    path = write_config(folder, short_raw(samples=3))
    result = runner.invoke(app, ["run", str(path), "--no-progress"])
    assert result.exit_code == 0, result.output
    return path, folder / "run"


def test_instance_idf_carries_sampled_values(short_config, tmp_path):
    config = load_config(short_config)
    result = runner.invoke(app, ["sample", str(short_config)])
    assert result.exit_code == 0, result.output
    samples = read_samples(config.run_dir)
    binary = find_energyplus()
    idd = idd_path(binary)
    sample = samples.loc[1].to_dict()
    files = write_instance(config, sample, tmp_path / "inst", idd)
    idf = open_idf(files.idfs["winter"], idd)
    glazing = idf.getobject("WINDOWMATERIAL:GLAZING", "ClearGlass3mm")
    assert glazing.Solar_Transmittance_at_Normal_Incidence == pytest.approx(
        0.837 * sample["glazing_solar_transmittance"], rel=1e-8)
    assert glazing.Dirt_Correction_Factor_for_Solar_and_Visible_Transmittance == pytest.approx(
        sample["glazing_dirt_correction"], rel=1e-8)
    gradient = idf.idfobjects["ROOMAIR:TEMPERATUREPATTERN:CONSTANTGRADIENT"][0]
    assert gradient.Temperature_Gradient == pytest.approx(sample["stratification_gradient"], rel=1e-8)
    reflectance = idf.idfobjects["SITE:GROUNDREFLECTANCE"][0]
    assert reflectance.July_Ground_Reflectance == pytest.approx(sample["ground_reflectance"])
    assert reflectance.December_Ground_Reflectance == pytest.approx(sample["ground_reflectance"])
    wall_curve = idf.getobject("CURVE:EXPONENT", "WallNaturalConvectionCurve")
    assert wall_curve.Coefficient2_Constant == pytest.approx(1.31 * sample["wall_stack_coefficient"])
    run_period = idf.idfobjects["RUNPERIOD"][0]
    assert (run_period.Begin_Month, run_period.Begin_Day_of_Month) == (12, 5)
    assert (run_period.End_Month, run_period.End_Day_of_Month) == (12, 8)
    schedule = idf.getobject("SCHEDULE:FILE", "FloorBoundaryTemperature")
    assert schedule.File_Name == str(files.boundary.resolve())
    # the boundary file holds the selected sequence during the run period
    from bpsflow.boundary import read_sequences

    sequences = read_sequences(config.run_dir.resolve() / "boundary_sequences.npz")
    table = pd.read_csv(files.boundary)
    chosen = sequences.sequence("floor", int(sample["floor_boundary_sampler"]))
    np.testing.assert_allclose(table["floor_c"].to_numpy()[sequences.hours], chosen, atol=6e-5)
    # and the weather file the sampled dry-bulb error (within the run period)
    from bpsflow.weather import read_epw

    base = read_epw(config.model.weather).columns["dry_bulb_temperature"]
    perturbed = read_epw(files.weather).columns["dry_bulb_temperature"]
    hours = sequences.hours
    assert np.allclose(perturbed[hours] - base[hours], sample["dry_bulb_error_c"], atol=0.051)


def test_short_run_produces_expected_outputs(finished_run):
    path, run_dir = finished_run
    manifest = read_manifest(run_dir)
    assert (manifest["status"] == "ok").all() and len(manifest) == 3
    results = read_results(run_dir)
    assert set(results["instance"]) == {0, 1, 2}
    heating = results[(results["test"] == "H-ST") & (results["output"] == "heating_power_w")]
    assert heating.groupby("instance").size().tolist() == [48, 48, 48]
    stamps = heating[heating["instance"] == 0]["timestamp"].sort_values()
    assert stamps.iloc[0] == pd.Timestamp("2025-12-05 01:00")   # hour-ending
    assert stamps.iloc[-1] == pd.Timestamp("2025-12-07 00:00")
    assert heating["value"].max() > 100 and heating["value"].min() >= 0
    air = results[(results["test"] == "H-FF")]
    assert air["value"].between(10, 50).all()
    # the instances differ: the sampled inputs reached EnergyPlus
    spread = heating.groupby("instance")["value"].mean()
    assert spread.std() > 0.1
    # cleaned: only outputs, SQLite and .err remain
    left = {p.name for p in (run_dir / "instances" / "000000").rglob("*") if p.is_file()}
    assert left == {"outputs.parquet", "eplusout.sql", "eplusout.err"}
    assert (run_dir / "figures" / "band_H-ST_heating_power_w.png").stat().st_size > 10_000


def test_resume_skips_finished_instances(finished_run):
    path, run_dir = finished_run
    outputs = run_dir / "instances" / "000001" / "outputs.parquet"
    stamp = outputs.stat().st_mtime_ns
    before = read_results(run_dir)
    result = runner.invoke(app, ["run", str(path), "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "ran 0, skipped 3 finished" in result.output
    assert outputs.stat().st_mtime_ns == stamp
    pd.testing.assert_frame_equal(read_results(run_dir), before)


def test_broken_instance_is_recorded_and_others_complete(tmp_path, monkeypatch):
    raw = short_raw(samples=3)
    path = write_config(tmp_path, raw)
    config = load_config(path)
    assert runner.invoke(app, ["sample", str(path)]).exit_code == 0
    samples = read_samples(config.run_dir)
    # Instance 1 gets an impossible glazing (transmittance + reflectance > 1): a fatal
    # EnergyPlus input error in that instance only.
    samples.loc[1, "glazing_solar_transmittance"] = 1.15
    samples.reset_index().to_parquet(config.run_dir / "samples.parquet", index=False)
    # The sample check refuses it before anything runs ...
    refused = runner.invoke(app, ["run", str(path), "--no-progress"])
    assert refused.exit_code == 2 and "instance 1" in " ".join(refused.output.split())
    assert not (config.run_dir / "instances").exists()
    # ... and an instance EnergyPlus fails for a reason no check foresees stays isolated.
    energyplus = get_backend("energyplus")
    monkeypatch.setattr(type(energyplus), "check_samples", lambda self, config, samples: None)
    result = runner.invoke(app, ["run", str(path), "--no-progress"])
    assert result.exit_code == 1
    assert "1 instance(s) failed" in result.output
    manifest = read_manifest(config.run_dir).set_index("instance")
    assert manifest.loc[1, "status"] == "failed"
    assert "Solar Transmittance" in manifest.loc[1, "error"]
    assert manifest.loc[[0, 2], "status"].tolist() == ["ok", "ok"]
    assert set(read_results(config.run_dir)["instance"]) == {0, 2}
    # a second run does not retry the failure unless asked, and then runs only it
    summary = run_ensemble(config, samples, energyplus, jobs=1, show_progress=False)
    assert (summary.ran, summary.failed) == (0, 1)
    samples.loc[1, "glazing_solar_transmittance"] = 1.0
    summary = run_ensemble(config, samples, energyplus, jobs=1, retry_failed=True,
                           show_progress=False)
    assert (summary.ran, summary.ok, summary.failed) == (1, 3, 0)
    assert set(read_results(config.run_dir)["instance"]) == {0, 1, 2}


def test_synth_writes_noisy_measurements_of_the_truth(tmp_path):
    raw = short_raw(samples=2)
    path = write_config(tmp_path, raw)
    truth = tmp_path / "truth.yaml"
    truth.write_text("seed: 3\nvalues: {stratification_gradient: 1.5, floor_boundary_sampler: 4}\n"
                     "noise: {heating_power_w: {kind: relative, bound: 0.3}}\n")
    result = runner.invoke(app, ["synth", str(path), "--truth", str(truth)])
    assert result.exit_code == 0, result.output
    measured = pd.read_csv(tmp_path / "run" / "truth" / "measured.csv", parse_dates=["timestamp"])
    assert list(measured.columns) == ["timestamp", "cooling_power_w", "heating_power_w",
                                      "zone_air_temperature_c"]
    assert len(measured) == 96
    # the truth instance runs in the truth folder's own simulation directory
    clean = pd.read_parquet(tmp_path / "run" / "truth" / "simulation" / "instances" / "000000"
                            / "outputs.parquet")
    heat = clean[clean["output"] == "heating_power_w"].set_index("timestamp")["value"]
    joined = measured.set_index("timestamp")["heating_power_w"].loc[heat.index]
    on = heat > 50
    relative = (joined[on] - heat[on]) / heat[on]
    assert 0.05 < relative.std() < 0.15          # bound 0.3 read as 3 std -> 0.1
    bad = tmp_path / "bad_truth.yaml"
    bad.write_text("values: {no_such_parameter: 1}\n")
    result = runner.invoke(app, ["synth", str(path), "--truth", str(bad)])
    assert result.exit_code == 2 and "values.no_such_parameter" in result.output


@pytest.mark.energyplus
def test_time_step_outputs_average_to_the_hourly_values(tmp_path):
    """A ``frequency: timestep`` output has steps_per_hour values per hour, ending on the step."""
    from bpsflow.simulation.ensemble import simulate_samples

    raw = short_raw(samples=2)
    raw["outputs"]["air_steps_c"] = {"variable": "Zone Mean Air Temperature",
                                     "key": raw["outputs"]["zone_air_temperature_c"]["key"],
                                     "unit": "C", "frequency": "timestep"}
    raw["model"]["tests"][1]["outputs"].append("air_steps_c")
    config = load_config(write_config(tmp_path, raw))
    nominal = {p.name: float(p.distribution.nominal) for p in config.parameters}
    tidy = simulate_samples(config, pd.DataFrame([nominal], index=pd.Index([0], name="instance")),
                            tmp_path / "work", get_backend("energyplus"))
    steps = tidy[tidy["output"] == "air_steps_c"].set_index("timestamp")["value"]
    hourly = tidy[tidy["output"] == "zone_air_temperature_c"].set_index("timestamp")["value"]
    per_hour = config.model.timesteps_per_hour
    assert len(steps) == len(hourly) * per_hour and steps.index.is_monotonic_increasing
    assert steps.index[0] == hourly.index[0] - pd.Timedelta(minutes=60 - 60 // per_hour)
    means = steps.groupby(steps.index.ceil("h")).mean()
    np.testing.assert_allclose(means.loc[hourly.index].to_numpy(), hourly.to_numpy(), atol=1e-9)


@pytest.mark.energyplus
def test_a_run_where_every_instance_fails_says_so_with_the_first_error(tmp_path, monkeypatch):
    raw = short_raw(samples=2)
    path = write_config(tmp_path, raw)
    config = load_config(path)
    assert runner.invoke(app, ["sample", str(path)]).exit_code == 0
    samples = read_samples(config.run_dir)
    samples["glazing_solar_transmittance"] = 1.15      # fatal in EnergyPlus, every instance
    samples.reset_index().to_parquet(config.run_dir / "samples.parquet", index=False)
    # The sample check would refuse it before running; this is about failures no check foresees.
    energyplus = get_backend("energyplus")
    monkeypatch.setattr(type(energyplus), "check_samples", lambda self, config, samples: None)
    result = runner.invoke(app, ["run", str(path), "--no-progress"])
    assert result.exit_code == 1
    assert "all 2 instances failed" in result.output
    assert "Solar Transmittance" in result.output          # the .err excerpt
    assert "Traceback" not in result.output
    assert read_manifest(config.run_dir)["status"].tolist() == ["failed", "failed"]


def test_an_idf_of_another_energyplus_release_is_named_with_what_to_do(tmp_path):
    """A 24.1 file gets a note naming its version and the transition; 25.2 files none."""
    from pathlib import Path

    from bpsflow.simulation.energyplus import ENERGYPLUS_VERSION, version_mismatch

    root = Path(__file__).resolve().parents[1]
    model = load_config(root / "configs" / "hydronic.yaml").model
    for shipped in ("flexlab_x3b.idf", "hydronic_office.idf", "office3zone.idf"):
        assert version_mismatch(model.model_copy(update={"idf": root / "sample_idf" / shipped})) \
            is None
    text = (root / "sample_idf" / "hydronic_office.idf").read_text()
    older = tmp_path / "older.idf"
    older.write_text(text.replace("Version,\n    25.2;", "Version,\n    24.1;  !- Version Identifier"))
    note = version_mismatch(model.model_copy(update={"idf": older}))
    assert note is not None
    assert "older.idf" in note and "24.1" in note and ENERGYPLUS_VERSION in note
    assert "transition" in note


def test_a_config_time_step_that_replaces_the_models_own_is_said():
    """office3zone runs its own 4 steps per hour; a config asking 6 replaces them, said."""
    from pathlib import Path

    from bpsflow.simulation.energyplus import timestep_note

    config = load_config(Path(__file__).resolve().parents[1] / "configs" / "office3zone.yaml")
    assert config.model.timesteps_per_hour == 4 and timestep_note(config) is None
    config.model.timesteps_per_hour = 6
    note = timestep_note(config)
    assert note is not None and "Timestep of 4" in note and "timesteps_per_hour: 4" in note
