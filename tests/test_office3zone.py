"""The foreign multi-zone building (configs/office3zone.yaml) through every command.

The model is an EnergyPlus test file the project did not write (see
sample_idf/README.md); nothing in the code or config names its objects for the
tool's sake. These tests run real EnergyPlus on short periods.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from bpsflow.cli import app
from bpsflow.config import load_config
from bpsflow.simulation.backend import get_backend
from bpsflow.simulation.ensemble import simulate_samples
from bpsflow.simulation.rundir import read_results

from conftest import ROOT

pytestmark = pytest.mark.energyplus
runner = CliRunner()
OFFICE = ROOT / "configs" / "office3zone.yaml"
KEPT = ("wall_insulation_conductivity", "infiltration_flow", "equipment_level",
        "glazing_solar_transmittance")
OUTPUTS = ("space3_heating_w", "space4_heating_w", "space1_air_temperature_c")


def office_raw(folder: Path, days: int = 14, idf: Path | None = None) -> dict:
    """The shipped office config on one short winter period, with absolute paths."""
    raw = yaml.safe_load(OFFICE.read_text())
    raw["model"]["idf"] = str(idf or ROOT / "sample_idf" / "office3zone.idf")
    raw["model"]["periods"] = [{"name": "winter", "start": "01-08",
                                "end": f"01-{7 + days:02d}"}]
    raw["model"]["tests"] = [{"name": "H", "period": "winter", "start": "01-08", "days": days,
                              "warmup_days": 2, "mode": "heating", "setpoint_c": 21.0,
                              "outputs": list(OUTPUTS)}]
    raw["parameters"] = [p for p in raw["parameters"] if p["name"] in KEPT]
    raw["outputs"] = {k: v for k, v in raw["outputs"].items() if k in OUTPUTS}
    raw["design"] = {"method": "lhs", "samples": 3, "seed": 1, "trajectories": 2, "levels": 4}
    raw["execution"] = {"jobs": 2, "run_dir": str(folder / "run")}
    return raw


def write(folder: Path, raw: dict, name: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def nominal_frame(config) -> pd.DataFrame:
    return pd.DataFrame([{p.name: float(p.distribution.nominal) for p in config.parameters}],
                        index=pd.Index([0], name="instance"))


@pytest.mark.slow
def test_two_setpoints_give_different_results_and_the_zones_follow_them(tmp_path):
    """The tests' setpoints reach the model's own thermostats (no silent no-op)."""
    means = {}
    for setpoint in (18.0, 23.0):
        raw = office_raw(tmp_path, days=4)
        raw["model"]["tests"][0]["setpoint_c"] = setpoint
        config = load_config(write(tmp_path / f"sp{setpoint:g}", raw, "office.yaml"))
        tidy = simulate_samples(config, nominal_frame(config), tmp_path / f"w{setpoint:g}",
                                get_backend("energyplus"))
        wide = tidy.pivot_table(index="timestamp", columns="output", values="value")
        # Heating holds the zone at the setpoint whenever it runs.
        heated = wide["space3_heating_w"] > 100
        air = wide.loc[heated, "space1_air_temperature_c"]
        assert heated.mean() > 0.5
        assert abs(air.median() - setpoint) < 0.5, (setpoint, air.describe())
        means[setpoint] = wide[["space3_heating_w", "space4_heating_w"]].mean()
    assert (means[23.0] > means[18.0] * 1.2).all(), means


def test_check_refuses_a_model_whose_thermostats_cannot_take_the_setpoints(tmp_path):
    text = (ROOT / "sample_idf" / "office3zone.idf").read_text()
    stripped = re.sub(r"\n\s*ZoneControl:Thermostat,.*?;", "\n", text, flags=re.S)
    assert "ZoneControl:Thermostat," not in stripped
    idf = tmp_path / "no_thermostats.idf"
    idf.write_text(stripped)
    path = write(tmp_path, office_raw(tmp_path, idf=idf), "office.yaml")
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 2
    assert "no ZoneControl:Thermostat" in result.output and "could not take effect" in result.output
    assert "Traceback" not in result.output
    # Listing a zone that is not conditioned is refused too.
    raw = office_raw(tmp_path)
    raw["model"]["thermostat_zones"] = ["PLENUM-1"]
    result = runner.invoke(app, ["check", str(write(tmp_path, raw, "plenum.yaml"))])
    assert result.exit_code == 2 and "PLENUM-1" in result.output


def test_the_surrogate_names_what_it_lacks_and_auto_says_energyplus_is_needed(tmp_path,
                                                                               monkeypatch):
    import bpsflow.simulation.energyplus as energyplus_backend

    raw = office_raw(tmp_path)
    raw["model"]["backend"] = "surrogate"
    result = runner.invoke(app, ["check", str(write(tmp_path, raw, "surrogate.yaml"))])
    assert result.exit_code == 2
    assert "single zone, the model has 6" in result.output
    assert "FenestrationSurface:Detailed window, the model has" in result.output
    # EnergyPlus is installed here: the message says to use it, not to install it
    assert "People" in result.output and "use --backend energyplus" in result.output
    monkeypatch.setattr(energyplus_backend, "find_energyplus", lambda override=None: None)
    raw["model"]["backend"] = "auto"
    result = runner.invoke(app, ["run", str(write(tmp_path, raw, "auto.yaml")), "--no-progress"])
    assert result.exit_code == 2
    assert "no EnergyPlus binary was found" in result.output and "make install" in result.output
    assert "Traceback" not in result.output


@pytest.mark.slow
def test_every_command_runs_on_the_foreign_building(tmp_path):
    """check → sample → run → synth → validate → sensitivity → calibrate → diagnose."""
    raw = office_raw(tmp_path, days=10)
    raw["calibration"] = {"outputs": ["space4_heating_w"], "resolution": "daily",
                          "holdout_days": 3, "design": {"runs": 12, "seed": 3},
                          "bayes": {"chains": 2, "warmup": 100, "samples": 100},
                          "posterior_runs": 2}
    # a smoke test of the command: one round, no signature runs of fixed inputs
    raw["diagnosis"] = {"output": "space4_heating_w", "holdout_days": 3, "suspects": [],
                        "max_rounds": 1, "start_screen": 4, "fit_starts": 1}
    path = write(tmp_path, raw, "office.yaml")
    truth = write(tmp_path, {"seed": 5, "values": {"infiltration_flow": 1.4}}, "truth.yaml")
    measured = tmp_path / "run" / "truth" / "measured.csv"
    steps = [["check", str(path)],
             ["sample", str(path)],
             ["run", str(path), "--no-progress"],
             ["synth", str(path), "--truth", str(truth)],
             ["validate", str(path), "--measured", str(measured)],
             ["sensitivity", str(path), "--measured", str(measured), "--no-progress"],
             ["calibrate", str(path), "--measured", str(measured), "--no-progress",
              "--allow-unconverged"],
             ["diagnose", str(path), "--measured", str(measured), "--no-progress"]]
    for step in steps:
        result = runner.invoke(app, step)
        assert result.exit_code == 0, (step[0], result.output)
    results = read_results(tmp_path / "run")
    assert set(results["output"]) == set(OUTPUTS) and results["instance"].nunique() == 3
    assert (tmp_path / "run" / "validation.json").is_file()
    assert (tmp_path / "run" / "morris" / "sensitivity.csv").is_file()
    assert (tmp_path / "run" / "calibration" / "calibration.json").is_file()
    assert (tmp_path / "run" / "diagnosis" / "diagnosis.json").is_file()


@pytest.mark.energyplus
def test_detailed_measurements_of_a_model_without_the_test_cells_objects(tmp_path):
    """No Site:GroundReflectance, no user convection curves: synth --detailed still writes
    every file, with EnergyPlus's defaults as the true values (it stopped half-written,
    after moving the earlier data aside)."""
    raw = office_raw(tmp_path, days=3)
    raw["detailed"] = {"zone": "SPACE1-1"}
    config = write(tmp_path, raw, "office.yaml")
    (tmp_path / "truth.yaml").write_text("values: {}\n")
    for _ in range(2):     # the second run moves the first one's files aside, whole
        result = runner.invoke(app, ["synth", str(config), "--truth", str(tmp_path / "truth.yaml"),
                                     "--detailed", "--backend", "energyplus"])
        assert result.exit_code == 0, result.output
    truth = tmp_path / "run" / "truth"
    record = json.loads((truth / "truth.json").read_text())["detailed"]
    assert record["ground_reflectance"] == pytest.approx(0.2)
    assert set(record["ground_reflectance_by_month"].values()) == {0.2}
    assert all(c["curve"] is None for c in record["convection"].values())
    assert (truth / "detailed.csv").is_file() and (truth / "detailed.json").is_file()
    earlier = next((truth / "previous").iterdir())
    assert {p.name for p in earlier.iterdir()} >= {"measured.csv", "truth.json", "detailed.csv"}
