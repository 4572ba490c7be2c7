"""A third building, unlike both shipped models, through every command (smoke test).

The model is EnergyPlus's ``1ZoneEvapCooler.idf`` test file (a one-zone house
with an evaporative-cooler air loop and an electric baseboard), its version line
set to 25.2; the config below was written by a new user from the README alone
(zone, surfaces and objects named only there). Nothing in bpsflow knows this
model: every command must run on it as on the shipped ones.
"""

from __future__ import annotations

import json
import shutil

import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from bpsflow.cli import app

from conftest import ROOT

pytestmark = [pytest.mark.energyplus, pytest.mark.slow]
runner = CliRunner()
MODEL = ROOT / "tests" / "data" / "evapcooler_house.idf"

CONFIG = {
    "model": {
        "backend": "energyplus", "idf": "model.idf",
        "weather": "USA_CO_Golden-NREL.724666_TMY3.epw",
        "periods": [{"name": "jan", "start": "01-06", "end": "01-19"}],
        "tests": [{"name": "jan-heat", "period": "jan", "start": "01-10", "days": 8,
                   "warmup_days": 2, "mode": "heating", "setpoint_c": 21, "setback_c": 16,
                   "setback_start_hour": 22, "setback_end_hour": 6,
                   "outputs": ["baseboard_w", "zone_air_c"]}],
    },
    "parameters": [
        {"name": "wall_resistance", "group": "materials", "mode": "relative",
         "distribution": {"type": "normal", "mean": 1.0, "std": 0.1, "lower": 0.7, "upper": 1.3},
         "targets": [{"object": "Material:NoMass", "name": "R13LAYER",
                      "field": "Thermal Resistance"}]},
        {"name": "roof_resistance", "group": "materials", "mode": "relative",
         "distribution": {"type": "normal", "mean": 1.0, "std": 0.1, "lower": 0.7, "upper": 1.3},
         "targets": [{"object": "Material:NoMass", "name": "R31LAYER",
                      "field": "Thermal Resistance"}]},
        {"name": "infiltration_flow", "group": "infiltration", "mode": "relative",
         "distribution": {"type": "uniform", "lower": 0.5, "upper": 2.0},
         "targets": [{"object": "ZoneInfiltration:DesignFlowRate", "name": "*",
                      "field": "Design Flow Rate"}]},
        {"name": "baseboard_efficiency", "group": "hvac", "mode": "absolute",
         "distribution": {"type": "uniform", "lower": 0.9, "upper": 1.0},
         "targets": [{"object": "ZoneHVAC:Baseboard:Convective:Electric", "name": "*",
                      "field": "Efficiency"}]},
    ],
    "outputs": {
        "baseboard_w": {"variable": "Baseboard Electricity Rate", "key": "Main Zone Baseboard",
                        "unit": "W"},
        "zone_air_c": {"variable": "Zone Mean Air Temperature", "key": "Main Zone", "unit": "C"},
    },
    "design": {"method": "lhs", "samples": 8, "seed": 1},
    "execution": {"jobs": 2, "run_dir": "run"},
    "calibration": {"design": {"runs": 24}, "bayes": {"chains": 2, "warmup": 100, "samples": 150},
                    "emulator": {"points": 120}, "posterior_runs": 4, "holdout_days": 2},
    # the shape screen (each candidate simulated at a trial size) is tested on both shipped
    # models and the three-zone office; here diagnose needs only to run through
    # and fits from the nominal start and one screened start (16 and 3 by default on EnergyPlus)
    "diagnosis": {"holdout_days": 2, "shape_screen": False, "start_screen": 4, "fit_starts": 1},
}
TRUTH = {"values": {"wall_resistance": 0.85, "infiltration_flow": 1.6,
                    "baseboard_efficiency": 0.93},
         "noise": {"zone_air_c": {"kind": "absolute", "bound": 0.3},
                   "baseboard_w": {"kind": "relative", "bound": 0.05}}}


def _ok(args: list[str]) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == 0, f"bpsflow {' '.join(args)}:\n{result.output}"


def test_every_command_on_a_third_building(tmp_path):
    shutil.copy(MODEL, tmp_path / "model.idf")
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump(CONFIG, sort_keys=False))
    (tmp_path / "truth.yaml").write_text(yaml.safe_dump(TRUTH))
    run = tmp_path / "run"
    c = str(config)
    _ok(["check", c])
    _ok(["sample", c])
    _ok(["run", c, "--no-progress"])
    results = pd.read_parquet(run / "results.parquet")
    assert set(results["output"]) == {"baseboard_w", "zone_air_c"}
    assert results["instance"].nunique() == 8
    _ok(["synth", c, "--truth", str(tmp_path / "truth.yaml"), "--no-progress"])
    measured = run / "truth" / "measured.csv"
    _ok(["validate", c, "--measured", str(measured), "--no-progress"])
    assert (run / "validation.csv").is_file()
    _ok(["calibrate", c, "--measured", str(measured), "--truth", str(run / "truth" / "truth.json"),
         "--allow-unconverged", "--no-progress"])
    record = json.loads((run / "calibration" / "calibration.json").read_text())
    calibrated = {p["name"] for p in record["parameters"] if p.get("posterior")}
    assert calibrated == {p["name"] for p in CONFIG["parameters"]}
    _ok(["diagnose", c, "--measured", str(measured), "--no-progress"])
    diagnosis = json.loads((run / "diagnosis" / "diagnosis.json").read_text())
    assert diagnosis.get("verdict")

