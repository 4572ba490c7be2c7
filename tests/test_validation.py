"""Validation: alignment errors are clear; thresholds and risks come out right on constructed ensembles."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from bpsflow.alignment import align, evaluation_hours
from bpsflow.cli import app
from bpsflow.config import load_config
from bpsflow.errors import BpsflowError
from bpsflow.validation import validate

from conftest import short_raw, write_config


def _tidy(config, values_by_instance: dict[int, np.ndarray]) -> pd.DataFrame:
    """Tidy results for the heating test only: each instance's values over its evaluated hours."""
    test = config.model.tests[0]
    hours = evaluation_hours(test, config.model.year)
    frames = [pd.DataFrame({"instance": i, "test": test.name, "output": "heating_power_w",
                            "timestamp": hours, "value": v}) for i, v in values_by_instance.items()]
    return pd.concat(frames, ignore_index=True)


@pytest.fixture
def heating_only(tmp_path):
    raw = short_raw()
    raw["model"]["tests"] = raw["model"]["tests"][:1]
    return load_config(write_config(tmp_path, raw))


def test_thresholds_and_risks_on_constructed_ensembles(heating_only):
    config = heating_only
    hours = evaluation_hours(config.model.tests[0], config.model.year)
    observed = np.full(len(hours), 100.0)
    measured = pd.DataFrame({"heating_power_w": observed}, index=hours)
    # internal instance k predicts 100 * (1 + k/100): nMAE = k/100, k = 1..10
    internal = _tidy(config, {k: observed * (1 + k / 100) for k in range(1, 11)})
    # invalid instance j predicts with nMAE = j/20, j = 1..10 -> 0.05 .. 0.5
    invalid = _tidy(config, {j: observed * (1 - j / 20) for j in range(1, 11)})
    [result] = validate(config, internal, measured, q=0.9, invalid_results=invalid)
    row = result.row
    np.testing.assert_allclose(np.sort(result.scores), np.arange(1, 11) / 100)
    assert row["threshold"] == pytest.approx(np.quantile(np.arange(1, 11) / 100, 0.9))  # 0.091
    assert row["type_ii_risk"] == pytest.approx(0.1)      # only 0.05 <= 0.091
    assert row["reduced_risk"] == pytest.approx(0.8)
    assert row["invalid_quantile"] == pytest.approx(np.quantile(np.arange(1, 11) / 20, 0.9))
    # the ensemble mean over-predicts by 5.5 %: NMBE is (y - yhat) summed over (n - 1) * ybar
    n = len(hours)
    assert row["nmbe"] == pytest.approx(-5.5 * n / (n - 1) / 100)
    assert row["guideline14_hourly"] == "pass"
    assert row["crps_estimator"] == "standard"


def test_missing_column_gap_and_range_errors_name_the_problem(heating_only):
    config = heating_only
    test = config.model.tests[0]
    hours = evaluation_hours(test, config.model.year)
    results = _tidy(config, {0: np.ones(len(hours))})
    with pytest.raises(BpsflowError, match="no column 'heating_power_w'"):
        align(config, results, pd.DataFrame({"other": 1.0}, index=hours), test,
              "heating_power_w", "m.csv")
    gappy = pd.DataFrame({"heating_power_w": 1.0}, index=hours).drop(hours[5])
    with pytest.raises(BpsflowError, match="lacks 1 of the 24 evaluated hours"):
        align(config, results, gappy, test, "heating_power_w", "m.csv")
    early = pd.DataFrame({"heating_power_w": 1.0}, index=hours - pd.Timedelta(days=30))
    with pytest.raises(BpsflowError, match="measured data cover"):
        align(config, results, early, test, "heating_power_w", "m.csv")
    # measured hour-beginning stamps (shifted by one hour) leave the last hour uncovered
    shifted = pd.DataFrame({"heating_power_w": 1.0}, index=hours - pd.Timedelta(hours=1))
    with pytest.raises(BpsflowError, match="measured data cover"):
        align(config, results, shifted, test, "heating_power_w", "m.csv")


def test_validate_cli_reports_missing_measured_column(tmp_path, heating_only):
    config = heating_only
    hours = evaluation_hours(config.model.tests[0], config.model.year)
    run_dir = config.run_dir
    run_dir.mkdir(parents=True)
    _tidy(config, {0: np.ones(len(hours))}).to_parquet(run_dir / "results.parquet")
    measured = tmp_path / "measured.csv"
    pd.DataFrame({"timestamp": hours, "zone_air_temperature_c": 20.0}).to_csv(measured, index=False)
    result = CliRunner().invoke(app, ["validate", str(config.source), "--measured", str(measured)])
    assert result.exit_code == 2
    assert "measured.csv" in result.output and "no column 'heating_power_w'" in result.output
    assert "Traceback" not in result.output
