"""Config validation: bad input names the file and key path and exits non-zero."""

from __future__ import annotations

from datetime import timedelta

import pytest
from typer.testing import CliRunner

from bpsflow.cli import app
from bpsflow.config import load_config
from bpsflow.errors import BpsflowError

from conftest import I600, i600_raw, short_raw, write_config

runner = CliRunner()


def test_shipped_config_loads_with_enough_inputs():
    config = load_config(I600)
    assert len(config.parameters) >= 40
    groups = {p.group for p in config.parameters}
    assert {"materials", "glazing", "convection", "weather", "boundary", "stratification"} <= groups
    assert [t.name for t in config.model.tests] == [
        "I600-C-CT", "I600-C-ST", "I600-C-FF", "I600-H-CT", "I600-H-ST", "I600-H-FF"]
    assert config.model.weather.is_file()


def _error(tmp_path, raw) -> str:
    path = write_config(tmp_path, raw)
    with pytest.raises(BpsflowError) as info:
        load_config(path)
    return str(info.value)


def test_bad_distribution_parameter_names_key_path(tmp_path):
    raw = i600_raw()
    raw["parameters"][2]["distribution"]["std"] = -0.1
    message = _error(tmp_path, raw)
    assert "case.yaml" in message
    assert f"parameters[2] ({raw['parameters'][2]['name']}).distribution.std" in message
    assert "greater than 0" in message


def test_inverted_uniform_bounds_are_rejected(tmp_path):
    raw = i600_raw()
    index = next(i for i, p in enumerate(raw["parameters"]) if p["name"] == "ground_reflectance")
    raw["parameters"][index]["distribution"].update(lower=0.4, upper=0.1)
    message = _error(tmp_path, raw)
    assert f"parameters[{index}] (ground_reflectance).distribution" in message
    assert "upper (0.1) must be greater than lower (0.4)" in message


def test_unknown_key_and_missing_key(tmp_path):
    raw = i600_raw()
    raw["design"]["sampels"] = 10
    assert "design.sampels: unknown key" in _error(tmp_path, raw)
    raw = i600_raw()
    del raw["model"]["idf"]
    assert "model.idf: required key is missing" in _error(tmp_path, raw)


def test_missing_idf_file_is_named(tmp_path):
    raw = i600_raw()
    raw["model"]["idf"] = str(tmp_path / "nope.idf")
    message = _error(tmp_path, raw)
    assert "model.idf" in message and "nope.idf" in message and "not found" in message


def test_test_outside_its_period_and_unknown_output(tmp_path):
    raw = short_raw()
    raw["model"]["tests"][1]["start"] = "12-08"
    assert "outside period 'winter'" in _error(tmp_path, raw)
    raw = short_raw()
    raw["model"]["tests"][0]["outputs"] = ["heating_energy_j"]
    assert "unknown output 'heating_energy_j'" in _error(tmp_path, raw)


def test_a_period_across_the_new_year_or_on_a_missing_leap_day_says_what_to_do(tmp_path):
    raw = short_raw()
    raw["model"]["periods"][0].update(start="12-10", end="01-20")
    message = _error(tmp_path, raw)
    assert "model.periods[0] (winter)" in message and "split" in message
    assert "12-10 to 12-31 and 01-01 to 01-20" in message and str(tmp_path) in message
    raw = short_raw()
    raw["model"]["periods"][0]["end"] = "02-29"
    assert "is not a leap year" in _error(tmp_path, raw)


def test_sampler_must_match_boundary_sequences(tmp_path):
    raw = short_raw(boundary_sequences=20)
    sampler = next(p for p in raw["parameters"] if p["distribution"]["type"] == "sampler")
    sampler["distribution"]["sequences"] = 7
    assert "must agree" in _error(tmp_path, raw)


@pytest.mark.energyplus
def test_unknown_idf_field_fails_before_anything_runs(tmp_path):
    raw = short_raw()
    raw["parameters"][0]["targets"][0]["field"] = "Conductivty"
    path = write_config(tmp_path, raw)
    result = runner.invoke(app, ["run", str(path), "--no-progress"])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
    assert "has no field 'Conductivty'" in result.output
    assert "parameters[0]" in result.output
    assert not (tmp_path / "run" / "instances").exists()


@pytest.mark.energyplus
def test_unknown_idf_object_name_is_named(tmp_path):
    raw = short_raw()
    raw["parameters"][0]["targets"][0]["name"] = "NoSuchMaterial"
    result = runner.invoke(app, ["check", str(write_config(tmp_path, raw))])
    assert result.exit_code == 2
    assert "no Material object named 'NoSuchMaterial'" in result.output


def test_cli_missing_config_file(tmp_path):
    result = runner.invoke(app, ["sample", str(tmp_path / "absent.yaml")])
    assert result.exit_code == 2
    assert "config file not found" in result.output
    assert "Traceback" not in result.output


def test_bad_weather_file_gives_clear_error(tmp_path):
    bad = tmp_path / "bad.epw"
    bad.write_text("this is not a weather file\n")
    raw = short_raw()
    raw["model"]["weather"] = str(bad)
    path = write_config(tmp_path, raw)
    from bpsflow.weather import read_epw

    config = load_config(path)
    with pytest.raises(BpsflowError, match="not an EPW weather file"):
        read_epw(config.model.weather)


def test_extends_merges_sections_and_parameters_by_name(tmp_path):
    from conftest import ROOT

    child = tmp_path / "refined.yaml"
    child.write_text(
        f"extends: {ROOT / 'configs' / 'i600.yaml'}\n"
        "design: {samples: 17}\n"
        "parameters:\n"
        "  - name: stratification_gradient\n"
        "    mode: absolute\n"
        "    distribution: {type: uniform, lower: 1.2, upper: 1.5}\n"
        "    targets: [{object: 'RoomAir:TemperaturePattern:ConstantGradient', name: CellGradient,"
        " field: Temperature Gradient}]\n"
        "  - name: extra_gain\n"
        "    distribution: {type: uniform, lower: 0.9, upper: 1.1}\n"
        "    mode: relative\n"
        "    targets: [{object: Material, name: SouthWallGypsum, field: Conductivity}]\n")
    base = load_config(I600)
    config = load_config(child)
    assert config.design.samples == 17 and config.design.seed == base.design.seed
    assert len(config.parameters) == len(base.parameters) + 1
    gradient = config.parameter("stratification_gradient").distribution
    assert (gradient.lower, gradient.upper) == (1.2, 1.5)
    assert config.model.idf == base.model.idf                 # base paths resolved at the base
    assert config.run_dir == base.run_dir
    assert [p.name for p in config.parameters][:3] == [p.name for p in base.parameters][:3]


def test_a_window_keeps_the_tests_that_evaluate_its_days_each_after_its_warm_up():
    """A window in a period's first test is cut to that test's days after its own warm-up;
    the other tests are dropped and the period is cut to the window."""
    from datetime import date

    from bpsflow.config import period_dates, test_dates, window_config

    config = load_config(I600)
    year = config.model.year
    opening = config.model.tests[0]
    _, evaluated, end = test_dates(opening, year)
    window = window_config(config, end - timedelta(days=1), end)
    assert [t.name for t in window.model.tests] == [opening.name]
    test = window.model.tests[0]
    start, kept_evaluated, kept_end = test_dates(test, year)
    assert (kept_evaluated, kept_end) == (end - timedelta(days=1), end)
    assert test.warmup_days == opening.warmup_days and start > test_dates(opening, year)[0]
    assert period_dates(window.model.periods[0], year) == (start, end)
    with pytest.raises(BpsflowError, match="no test of model.tests evaluates"):
        window_config(config, date(year, 9, 1), date(year, 9, 7))


def test_a_window_after_other_tests_of_its_period_keeps_their_history():
    """A free-floating test that follows a conditioned one starts from the state that test
    left: the window then runs its period from the start, the earlier tests as they are
    (cut at the test's own warm-up, a heavy warehouse's free float came out 0.5 K colder)."""
    from datetime import date

    from bpsflow.config import period_dates, test_dates, window_config

    config = load_config(I600)
    year = config.model.year
    first, last = date(year, 7, 20), date(year, 7, 21)
    window = window_config(config, first, last)
    summer = next(p for p in config.model.periods if p.name == "summer")
    assert [p.name for p in window.model.periods] == ["summer"]
    assert period_dates(window.model.periods[0], year) == (period_dates(summer, year)[0], last)
    originals = {t.name: t for t in config.model.tests}
    inside = [t for t in config.model.tests
              if test_dates(t, year)[1] <= last and test_dates(t, year)[2] >= first]
    before = [t for t in config.model.tests if t.period == "summer" and t not in inside]
    assert {t.name for t in window.model.tests} == {t.name for t in inside + before}
    for test in window.model.tests:
        original = originals[test.name]
        assert test_dates(test, year)[0] == test_dates(original, year)[0]  # its whole history
        if original in before:
            assert test == original
        else:
            assert test_dates(test, year)[2] == min(test_dates(original, year)[2], last)


def test_an_overlay_problem_is_named_at_its_position_in_the_overlay(tmp_path):
    """The overlay's only parameter lacks its targets: it is parameters[0] of the overlay
    the user wrote, wherever the merge puts it."""
    from bpsflow.config import with_overlay
    from bpsflow.errors import BpsflowError

    config = load_config(I600)
    last = config.parameters[-1].name
    source = tmp_path / "intervention.yaml"
    source.write_text("change: {}\n")
    overlay = {"parameters": [{"name": last,
                               "distribution": {"type": "uniform", "lower": 2.0, "upper": 1.0}}]}
    with pytest.raises(BpsflowError) as caught:
        with_overlay(config, overlay, source, where="change.overlay")
    assert f"change.overlay.parameters[0] ({last})" in str(caught.value)
    assert len(config.parameters) > 1 and f"parameters[{len(config.parameters) - 1}]" \
        not in str(caught.value)


def test_a_parameter_given_by_name_keeps_the_keys_it_does_not_give(tmp_path):
    """An overlay or child config fixing a parameter need not repeat its targets."""
    from bpsflow.config import with_overlay

    config = load_config(I600)
    base = config.parameters[-1]
    source = tmp_path / "intervention.yaml"
    source.write_text("change: {}\n")
    changed = with_overlay(config, {"parameters": [
        {"name": base.name, "distribution": {"type": "constant", "value": 1.0}}]}, source)
    after = next(p for p in changed.parameters if p.name == base.name)
    assert after.distribution.type == "constant" and after.targets == base.targets
    assert after.mode == base.mode and len(changed.parameters) == len(config.parameters)


def test_a_normal_whose_mean_is_outside_its_bounds_is_said_by_check(tmp_path):
    raw = short_raw()
    first = raw["parameters"][0]
    first["distribution"] = {"type": "normal", "mean": 1.0, "std": 0.4, "lower": 1.5,
                             "upper": 2.0}
    result = runner.invoke(app, ["check", str(write_config(tmp_path, raw)), "--no-run"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0, result.output
    assert f"parameters[0] ({first['name']}): the normal's mean 1 is below its bounds" in text
    raw["parameters"][0]["distribution"].update(lower=0.8, upper=1.2)
    (tmp_path / "inside").mkdir()
    result = runner.invoke(app, ["check", str(write_config(tmp_path / "inside", raw)), "--no-run"])
    assert result.exit_code == 0 and "is below its bounds" not in result.output


def test_keys_lists_the_schema_with_types_and_defaults():
    """``bpsflow keys`` reads the pydantic schema: keys only shown by example are listed."""
    from bpsflow.config import Config
    from bpsflow.diagnosis.settings import DiagnosisSettings
    from bpsflow.schema import config_keys

    rows = {key: (kind, default) for key, kind, default in config_keys(Config)}
    assert rows["diagnosis.holdout_days"] == ("integer", "7")
    assert rows["model.year"] == ("integer", "2025")
    assert rows["model.tests[].setback_start_hour"] == ("integer", "18")
    assert rows["parameters[].distribution(type: normal).std"][1] == "required"
    assert rows["outputs.<name>.unit"][0] == "text"
    # every diagnosis setting, whatever is added later
    assert {f"diagnosis.{name}" for name in DiagnosisSettings.model_fields} <= set(rows)
    result = runner.invoke(app, ["keys", "calibration.bayes"])
    assert result.exit_code == 0, result.output
    assert "calibration.bayes.chains" in result.output and "model.year" not in result.output
    result = runner.invoke(app, ["keys", "diagnostics"])
    assert result.exit_code == 2 and "no config key 'diagnostics'" in result.output
