"""The hydronic office case (seed chapter 4): the model runs its own controls (mode model),
one config drives the prototype and the room-by-room baseline, and bad mixes are refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from bpsflow.cli import app
from bpsflow.config import load_config
from bpsflow.errors import BpsflowError
from bpsflow.simulation.targets import matches_name

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_name_patterns():
    assert matches_name("Cellular Office*", "Cellular Office")
    assert matches_name("cellular office*", "Cellular Office 07")
    assert matches_name("Cellular Office*Heating Setpoint", "Cellular Office 07 Own Heating Setpoint")
    assert not matches_name("Cellular Office*", "Open Office")
    assert not matches_name("Cellular Office", "Cellular Office 07")
    assert matches_name("Office [A]", "office [a]")      # brackets are plain characters


def _write(tmp_path: Path, tests: list[dict]) -> Path:
    raw = {"extends": str(CONFIGS / "hydronic.yaml"), "model": {"tests": tests}}
    path = tmp_path / "case.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_model_mode_cannot_mix_with_tool_setpoints(tmp_path):
    own = {"name": "A", "period": "spring", "start": "02-13", "days": 8, "warmup_days": 2,
           "mode": "model", "outputs": ["heating_kwh"]}
    tool = {**own, "name": "B", "mode": "heating", "setpoint_c": 21}
    with pytest.raises(BpsflowError, match="mode model"):
        load_config(_write(tmp_path, [own, tool]))
    with pytest.raises(BpsflowError, match="takes no setpoint_c"):
        load_config(_write(tmp_path, [{**own, "setpoint_c": 21}]))


def test_surrogate_refuses_the_hydronic_model():
    from bpsflow.surrogate.support import unsupported_features

    lacking = unsupported_features(load_config(CONFIGS / "hydronic.yaml"))
    assert any("mode model" in reason for reason in lacking)
    # the plant's many object types: the most common named, the long tail counted
    physics = next(reason for reason in lacking if reason.startswith("no physics for"))
    assert physics.count("(") <= 13 and "more object types" in physics


@pytest.mark.energyplus
@pytest.mark.slow
def test_prototype_and_baseline_run_their_own_controls(tmp_path):
    """Two prototype instances and the baseline truth: the radiators heat on weekdays only
    (the model's schedule, not the tool's), and one config's targets reach both models."""
    runner = CliRunner()
    run_dir = tmp_path / "run"
    config = tmp_path / "two.yaml"
    config.write_text(yaml.safe_dump({"extends": str(CONFIGS / "hydronic.yaml"),
                                      "design": {"samples": 2},
                                      "execution": {"run_dir": str(run_dir)}}))
    result = runner.invoke(app, ["sample", str(config)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["run", str(config), "--no-progress"])
    assert result.exit_code == 0, result.output
    results = pd.read_parquet(run_dir / "results.parquet")
    heating = results[results["output"] == "heating_kwh"]
    starts = heating["timestamp"] - pd.Timedelta(hours=1)
    weekend = starts.dt.day_of_week >= 5
    night = (starts.dt.hour < 6) | (starts.dt.hour >= 19)
    assert heating.loc[weekend | night, "value"].abs().max() < 1e-6
    assert heating.loc[~weekend & ~night, "value"].mean() > 1.0       # kWh per hour
    temperature = results[results["output"] == "meeting_room_air_temperature_c"]["value"]
    assert 10 < temperature.min() and temperature.max() < 30
    truth_dir = tmp_path / "truth"
    result = runner.invoke(app, ["synth", str(CONFIGS / "hydronic_baseline.yaml"), "--truth",
                                 str(CONFIGS / "hydronic_truth.yaml"), "--run-dir", str(truth_dir)])
    assert result.exit_code == 0, result.output
    raw = pd.read_csv(truth_dir / "truth" / "measured.csv", parse_dates=["timestamp"])
    assert {"heating_kwh", "electricity_kwh", "meeting_room_air_temperature_c"} <= set(raw)
    # the baseline's meters report every 15 minutes; the heating meter in 0.5 kWh steps
    assert (raw["timestamp"].diff().dropna() == pd.Timedelta(minutes=15)).mean() > 0.99
    assert np.allclose(raw["heating_kwh"] / 0.5, np.round(raw["heating_kwh"] / 0.5))
    from bpsflow.measured import read_measured

    hourly = read_measured(truth_dir / "truth" / "measured.csv",
                           load_config(CONFIGS / "hydronic.yaml")).frame
    simulated = heating.groupby("instance")["value"].sum().mean()
    window = hourly.index.isin(heating["timestamp"])
    # the baseline is another model of the same floor: the same order of heat
    assert 0.5 < hourly.loc[window, "heating_kwh"].sum() / simulated < 2.0


def test_meter_reads_whole_increments_and_resets_at_midnight():
    from bpsflow.synth import metered

    stamps = pd.date_range("2017-03-20 00:15", periods=2 * 96, freq="15min")
    values = np.full(len(stamps), 0.3)                     # 0.3 kWh per quarter hour
    read = metered(values, stamps, 1.0, pd.Timedelta(minutes=15))
    assert set(np.round(read, 9)) <= {0.0, 1.0}            # whole increments only
    first_day = (stamps - pd.Timedelta(minutes=15)).normalize() == stamps[0].normalize()
    # 96 x 0.3 = 28.8 kWh a day: the meter shows 28, and starts again at midnight
    assert read[first_day].sum() == pytest.approx(28.0)
    assert read[~first_day].sum() == pytest.approx(28.0)
    assert read[0] == 0.0 and read[3] == 1.0               # 0.3, 0.6, 0.9, 1.2 -> 0, 0, 0, 1
    hourly = read.reshape(-1, 4).sum(axis=1)
    assert set(np.round(hourly, 9)) <= {1.0, 2.0}          # hourly sums from stepped readings


def test_model_mode_heating_rows_are_kept_where_the_meter_reads():
    """The tool knows no heating schedule of a model-mode test: its heating rows are paired
    (only the idle rule drops rows), not dropped as 'system off'."""
    from bpsflow.calibration.design import _aggregate

    config = load_config(CONFIGS / "hydronic.yaml")
    hours = pd.date_range("2017-02-20 01:00", periods=48, freq="h")
    frame, _, _ = _aggregate(config, config.model.tests[0], "heating_kwh", hours,
                             np.ones(48), np.ones((48, 2)), "hourly")
    assert frame["on"].all()


def test_diagnosis_leaves_warm_up_days_out():
    """Warm-up days are simulated, not evaluated: diagnose fits the evaluated hours only."""
    from bpsflow.diagnosis.settings import DiagnosisSettings
    from bpsflow.diagnosis.workflow import prepare

    config = load_config(CONFIGS / "hydronic.yaml")
    hours = pd.date_range("2017-02-13 01:00", "2017-03-27 00:00", freq="h")
    rng = np.random.default_rng(0)
    measured = pd.DataFrame({"heating_kwh": rng.random(len(hours)),
                             "electricity_kwh": rng.random(len(hours)),
                             "meeting_room_air_temperature_c": 20 + rng.random(len(hours))},
                            index=pd.DatetimeIndex(hours, name="timestamp"))
    data = prepare(config, measured, DiagnosisSettings())
    assert data.timestamps[0] == pd.Timestamp("2017-02-20 01:00")      # after 7 warm-up days
    assert data.timestamps[-1] == pd.Timestamp("2017-03-27 00:00")
    assert len(data.timestamps) == 35 * 24
    assert data.unmeasured == 0
    # gaps inside the evaluated days are left out and counted (diagnose says so); one in a
    # warm-up day is not evaluated anyway
    holed = measured.copy()
    gaps = pd.DatetimeIndex(["2017-02-14 05:00", "2017-02-21 10:00", "2017-03-01 11:00",
                             "2017-03-01 12:00"])
    holed.loc[gaps, "heating_kwh"] = np.nan
    data = prepare(config, holed, DiagnosisSettings())
    assert data.unmeasured == 3 and len(data.timestamps) == 35 * 24 - 3
    assert not data.timestamps.isin(gaps).any()


def _field_values(idf: Path, object_type: str, name_prefix: str, position: int,
                  contains: str = "") -> list[float]:
    """A field of every object whose name starts with ``name_prefix`` (and holds
    ``contains``), read by plain text."""
    body = "\n".join(line.split("!", 1)[0] for line in idf.read_text().splitlines())
    values = []
    for chunk in body.split(";"):
        fields = [f.strip() for f in chunk.split(",")]
        if fields[0].upper() == object_type.upper() and fields[1].startswith(name_prefix) \
                and contains in fields[1]:
            values.append(float(fields[position]))
    return values


def test_equivalent_truth_of_the_prototype_model():
    """The prototype office (multiplier 16) must carry the mean of the 16 rooms it stands for."""
    from bpsflow.equivalent_truth import equivalent_values

    baseline = load_config(CONFIGS / "hydronic_baseline.yaml")
    prototype = load_config(CONFIGS / "hydronic.yaml")
    idf = Path(baseline.model.idf)
    truth = {"lighting_power_cellular_office": 1.1, "setpoint_cellular_office": 0.6,
             "glazing_u_value": 1.15, "radiator_capacity": 0.95}
    found = equivalent_values(baseline, truth, prototype)
    # Lights: type, Name, Zone, Schedule, Method, Level, Watts/Area (position 6)
    rooms = _field_values(idf, "Lights", "Cellular Office ", 6)
    (own,) = _field_values(Path(prototype.model.idf), "Lights", "Cellular Office", 6)
    assert len(rooms) == 16
    assert found.values["lighting_power_cellular_office"] == pytest.approx(
        1.1 * np.mean(rooms) / own, rel=1e-9)
    # each room's own setpoint schedule; the shared one nothing uses counts for no room
    setpoints = _field_values(idf, "Schedule:Constant", "Cellular Office ", 3, contains=" Own ")
    (nominal,) = _field_values(Path(prototype.model.idf), "Schedule:Constant",
                               "Cellular Office Heating Setpoint", 3)
    assert len(setpoints) == 16
    assert found.values["setpoint_cellular_office"] == pytest.approx(
        np.mean(setpoints) + 0.6 - nominal, abs=1e-9)
    assert abs(found.values["setpoint_cellular_office"] - 0.6) > 0.05   # the rooms do move it
    assert found.values["glazing_u_value"] == pytest.approx(1.15)       # one shared material
    # the prototype's radiator is sized for its multiplied zone: no like-for-like equivalent
    assert found.values["radiator_capacity"] == 0.95
    assert "truth kept" in found.how["radiator_capacity"]
