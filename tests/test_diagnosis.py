"""bpsflow diagnose: hidden effects must be found, named, fixed and measured; nulls must not be.

Every "measured" file here comes from a truth model that the code under test
never sees: ``diagnose`` is given the base config and the measurement file
only (see :mod:`bpsflow.diagnosis.hidden`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from bpsflow.cli import app
from bpsflow.config import load_config
from bpsflow.diagnosis.extensions import EXTENSIONS, extend_config, gain_blocks, year_hours
from bpsflow.diagnosis.fitting import Problem, fit_many
from bpsflow.diagnosis.hidden import EXPECTED, MEASURE, make_case
from bpsflow.diagnosis.workflow import diagnose, diagnose_many
from bpsflow.synth import read_measured

ROOT = Path(__file__).resolve().parents[1]
DIAGNOSIS = ROOT / "configs" / "diagnosis.yaml"

#: The fitted parameters' true values: the base model starts away from them.
FITTED_TRUTH = {"glazing_dirt_correction": 0.92, "south_wall_insulation_conductivity": 1.05,
                "wall_stack_coefficient": 1.2, "return_air_offset": -0.2}


def base_config(folder: Path, days: int = 24, backend: str = "surrogate",
                extra: dict | None = None) -> Path:
    """configs/diagnosis.yaml over ``days`` days (3 warm-up, the last 7 held out)."""
    raw = {"extends": str(DIAGNOSIS),
           "model": {"backend": backend,
                     "periods": [{"name": "diagnosis", "start": "11-01",
                                  "end": f"11-{days:02d}"}],
                     "tests": [{"name": "H-DG", "period": "diagnosis", "start": "11-01",
                                "days": days, "warmup_days": 3, "mode": "heating",
                                "setpoint_c": 30.0, "outputs": ["heating_power_w"]}]},
           "execution": {"jobs": 2, "run_dir": str(folder / "base_run")}}
    if extra:
        raw.update(extra)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "base.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def surrogate_base(tmp_path_factory) -> Path:
    return base_config(tmp_path_factory.mktemp("diagnosis_base"))


def quiet(_text: str) -> None:
    pass


# ---------------------------------------------------------------------------
# Hidden model-form effects on the surrogate

CASES = {"wind_infiltration": 0.004, "office_gain": 150.0, "east_aperture": 1.0,
         "constant_infiltration": 0.02}


@pytest.mark.parametrize("effect", sorted(CASES))
def test_hidden_model_form_effect_is_found_and_fixed(effect, surrogate_base, tmp_path):
    value = CASES[effect]
    case = make_case(surrogate_base, tmp_path / "truth", effect, value, FITTED_TRUTH, seed=3)
    result = diagnose(load_config(surrogate_base), read_measured(case.measured),
                      tmp_path / "out", backend="surrogate", announce=quiet)
    drivers, extension = EXPECTED[effect]
    assert result.verdict == "model_form"
    assert result.cause["driver"] in drivers
    assert result.cause["extension"] == extension
    accepted = [e for e in result.extensions if e["accepted"]]
    assert accepted[0]["name"] == extension
    assert accepted[0]["fitted"][MEASURE[effect]] == pytest.approx(value, rel=0.10)
    assert result.gain["after"] < 0.5 * result.gain["before"]
    assert result.gain["nmcrps_after"] < result.gain["nmcrps_before"]
    # nothing significant is left once the extension is in
    assert result.rounds[-1]["significant"] == []


def test_pure_parameter_error_names_the_parameter(surrogate_base, tmp_path):
    """All solar gains 30 % higher than the model's fixed irradiance gain says."""
    truth = {**FITTED_TRUTH, "global_irradiance_gain": 1.3}
    case = make_case(surrogate_base, tmp_path / "truth", None, 0.0, truth, seed=5,
                     noise_bound=0.005)
    result = diagnose(load_config(surrogate_base), read_measured(case.measured),
                      tmp_path / "out", backend="surrogate", announce=quiet)
    assert result.verdict == "parameter"
    assert result.cause["parameter"] == "global_irradiance_gain"
    assert result.cause["extension"] is None
    assert result.parameter_fit["fitted"] == pytest.approx(1.3, abs=0.03)
    assert result.gain["after"] < 0.5 * result.gain["before"]
    assert not [e for e in result.extensions if e["accepted"]]


def test_cli_null_case_writes_the_contract_and_invents_no_cause(surrogate_base, tmp_path):
    """Autocorrelated sensor noise only: verdict none, diagnosis.json in the DESIGN §8 shape."""
    case = make_case(surrogate_base, tmp_path / "truth", None, 0.0, FITTED_TRUTH, seed=11)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["diagnose", str(surrogate_base), "--measured",
                                      str(case.measured), "--out", str(out), "--no-progress"])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "diagnosis.json").read_text())
    assert record["verdict"] == "none"
    assert set(record["cause"]) == {"driver", "parameter", "extension", "summary"}
    assert record["cause"]["driver"] is None and record["cause"]["extension"] is None
    assert {"name", "effect", "p_value", "significant"} <= set(record["drivers"][0])
    assert not any(d["significant"] for d in record["drivers"])
    assert record["extensions"] == []
    assert record["gain"]["metric"] == "cvrmse"
    assert record["gain"]["before"] == record["gain"]["after"]
    names = {d["name"] for d in record["drivers"]}
    assert {"outdoor_air_temperature", "wind_speed", "hour_of_day", "weekend",
            "incident_solar_south", "global_horizontal_radiation"} <= names
    for figure in ("signature_outdoor_temperature.png", "residual_heatmap.png",
                   "residual_acf.png", "heldout.png"):
        assert (out / "figures" / figure).stat().st_size > 5000
    assert "**Verdict: none.**" in (out / "diagnosis.md").read_text()
    table = pd.read_csv(out / "residuals.csv")
    assert len(table) == record["hours"]["calibration"] + record["hours"]["heldout"]


def test_false_model_form_verdicts_stay_rare_over_null_datasets(surrogate_base, tmp_path):
    """20 null datasets (different noise seeds, AR(1) noise): ≤ 10 % false model_form."""
    case = make_case(surrogate_base, tmp_path / "truth", None, 0.0, FITTED_TRUTH, seed=0,
                     noise_bound=0.0)
    clean = read_measured(case.measured)
    from bpsflow.diagnosis.hidden import null_measurements

    noisy = null_measurements(clean["heating_power_w"].to_numpy(), list(range(100, 120)))
    datasets = [clean.assign(heating_power_w=values) for values in noisy]
    results = diagnose_many(load_config(surrogate_base), datasets,
                            [tmp_path / f"out{i}" for i in range(len(datasets))],
                            backend="surrogate", announce=quiet)
    false_alarms = sum(r.verdict == "model_form" for r in results)
    assert false_alarms <= 2, [r.cause for r in results]
    # the datasets really differ, and the base fits are good (the noise is all there is)
    assert len({round(r.scorecard["heldout"]["cvrmse"], 6) for r in results}) == len(results)
    assert max(r.scorecard["heldout"]["cvrmse"] for r in results) < 0.03


# ---------------------------------------------------------------------------
# Pieces with known answers


def test_gain_blocks_recover_a_block_confounded_with_a_fitted_response():
    """A weekday 09–17 block plus a solar-like confounder the fit had bent towards."""
    hours = pd.date_range("2025-11-03 01:00", periods=24 * 14, freq="h")
    start = hours - pd.Timedelta(hours=1)
    weekday = np.asarray(start.day_of_week < 5)
    hour = np.asarray(start.hour)
    block = (weekday & (hour >= 9) & (hour < 17)).astype(float)
    solar = np.clip(np.sin((hour - 6) / 12 * np.pi), 0, None) * 100.0
    rng = np.random.default_rng(1)
    residual = -150.0 * block + 0.4 * solar + rng.normal(0, 5, len(hours))
    found = gain_blocks(pd.Series(residual, index=hours), output_sign=-1.0,
                        fitted_jacobian=solar[:, None], count=3)
    profile, best = found[0]
    assert (best["day_type"], best["start_hour"], best["end_hour"]) == ("weekdays", 9, 17)
    assert best["level"] == pytest.approx(150.0, rel=0.05)
    assert profile["profile"].sum() == 8 and profile.loc[(1, 12), "profile"] == 0


def test_fit_many_finds_known_least_squares_optima(surrogate_base):
    """A linear 'simulator': the fits must equal the closed-form least-squares solutions."""
    config = load_config(surrogate_base)
    parameters = [p for p in config.parameters
                  if p.name in ("glazing_dirt_correction", "wall_stack_coefficient")]
    hours = 200
    rng = np.random.default_rng(0)
    basis = rng.normal(size=(hours, 2)) * [50.0, 20.0]

    def simulate(samples: pd.DataFrame) -> np.ndarray:
        theta = samples[["glazing_dirt_correction", "wall_stack_coefficient"]].to_numpy()
        return 500.0 + theta @ basis.T

    truths = [(0.8, 1.1), (0.95, 0.7)]
    calibration = np.arange(hours) < 150
    problems = []
    for glazing, wall in truths:
        measured = 500.0 + basis @ [glazing, wall] + rng.normal(0, 1.0, hours)
        problems.append(Problem({p.name: 1.0 for p in config.parameters}, parameters,
                                measured, calibration))
    fits = fit_many(simulate, problems)
    for fit, problem in zip(fits, problems):
        design = basis[calibration]
        # the objective's extra mean term makes it a weighted least squares
        y = problem.measured[calibration] - 500.0
        rows = np.vstack([design, design.mean(axis=0) * np.sqrt(len(y))])
        target = np.concatenate([y, [y.mean() * np.sqrt(len(y))]])
        expected = np.linalg.lstsq(rows, target, rcond=None)[0]
        assert fit.values == pytest.approx(expected, abs=2e-3)
        assert fit.jacobian[:, 0] == pytest.approx(basis[:, 0], rel=1e-6)


def test_extension_variants_coexist_and_are_nested_at_zero(surrogate_base, tmp_path):
    """Two variants of one extension in one model; at zero the model is the original."""
    from bpsflow.diagnosis.fitting import output_simulator

    config = load_config(surrogate_base)
    extension = EXTENSIONS["internal_gain_schedule"]
    hours = year_hours(config.model.year)
    night = (hours - pd.Timedelta(hours=1)).hour     # rows are hour-ending; hour start here
    on = pd.Series(((night >= 1) & (night < 6)).astype(float), index=hours)
    union = extend_config(config, extension, tmp_path / "a", on, variant=1)
    union = extend_config(union, extension, tmp_path / "b", 1 - on, variant=2)
    names = [p.name for p in union.parameters if p.group == "extension"]
    assert names == ["scheduled_gain_w_v1", "scheduled_gain_w_v2"]
    timestamps = pd.date_range("2025-11-04 01:00", periods=24 * 4, freq="h")
    simulate = output_simulator(union, "heating_power_w", timestamps, backend="surrogate",
                                work_dir=tmp_path / "runs")
    sample = {p.name: float(p.distribution.nominal) for p in config.parameters}
    rows = [{**sample, "scheduled_gain_w_v1": 0.0, "scheduled_gain_w_v2": 0.0},
            {**sample, "scheduled_gain_w_v1": 100.0, "scheduled_gain_w_v2": 0.0}]
    predicted = simulate(pd.DataFrame(rows))
    original = output_simulator(config, "heating_power_w", timestamps, backend="surrogate",
                                work_dir=tmp_path / "runs0")(pd.DataFrame([sample]))
    np.testing.assert_allclose(predicted[0], original[0], rtol=0, atol=1e-9)
    start_hour = (timestamps - pd.Timedelta(hours=1)).hour
    change = predicted[1] - predicted[0]
    active = (start_hour >= 1) & (start_hour < 6)
    heating = predicted[0] > 150.0      # sunny hours need no heating: a gain cannot lower it
    assert (active & heating).sum() >= 15
    assert change[active & heating] == pytest.approx(-100.0, abs=1.0)
    assert np.abs(change[~active]).max() < 1.0


def test_bad_diagnosis_input_names_the_key(surrogate_base, tmp_path):
    measured = tmp_path / "measured.csv"
    measured.write_text("timestamp,cooling_power_w\n2025-11-04 01:00:00,1\n")
    result = CliRunner().invoke(app, ["diagnose", str(surrogate_base), "--measured",
                                      str(measured), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "heating_power_w" in result.output and "Traceback" not in result.output
    bad = base_config(tmp_path / "bad", extra={"diagnosis": {"output": "nope"}})
    result = CliRunner().invoke(app, ["diagnose", str(bad), "--measured", str(measured)])
    assert result.exit_code == 2
    assert "diagnosis.output" in result.output


# ---------------------------------------------------------------------------
# EnergyPlus: the same questions on the real engine (short runs)


@pytest.mark.energyplus
@pytest.mark.parametrize("effect,value", [("wind_infiltration", 0.004),
                                          ("office_gain", 150.0)])
def test_hidden_effect_on_energyplus(effect, value, tmp_path):
    base = base_config(tmp_path / "base", days=20, backend="energyplus",
                       extra={"diagnosis": {"output": "heating_power_w", "holdout_days": 5,
                                            "parameters": ["glazing_dirt_correction",
                                                           "return_air_offset"],
                                            "parameter_candidates": 1, "gain_blocks": 3,
                                            "suspects": ["global_irradiance_gain",
                                                         "exterior_wind_coefficient"],
                                            "max_rounds": 2}})
    case = make_case(base, tmp_path / "truth", effect, value, {
        "glazing_dirt_correction": 0.92, "return_air_offset": -0.2}, seed=3,
        backend="energyplus")
    result = diagnose(load_config(base), read_measured(case.measured), tmp_path / "out",
                      backend="energyplus", jobs=2, announce=quiet)
    drivers, extension = EXPECTED[effect]
    assert result.verdict == "model_form"
    assert result.cause["driver"] in drivers
    assert result.cause["extension"] == extension
    accepted = next(e for e in result.extensions if e["accepted"])
    assert accepted["fitted"][MEASURE[effect]] == pytest.approx(value, rel=0.15)
    assert result.gain["after"] < result.gain["before"]
