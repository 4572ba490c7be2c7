"""Bad-input battery: the config and the truth file (one case per class, through the CLI)."""

from __future__ import annotations

import os

import pytest
import yaml
from battery import assert_clean_error, invoke

from conftest import short_raw, write_config


def _surrogate_raw() -> dict:
    raw = short_raw()
    raw["model"]["backend"] = "surrogate"
    return raw


def test_a_binary_config_is_refused_without_echoing_it(tmp_path):
    path = tmp_path / "binary.yaml"
    path.write_bytes(b"\x85\xff" + os.urandom(200))
    text = assert_clean_error(invoke("check", path), str(path), "not a UTF-8 text file")
    assert "\ufffd" not in text


def test_a_folder_given_as_config_is_named(tmp_path):
    assert_clean_error(invoke("check", tmp_path), str(tmp_path),
                       "is a folder; expected a YAML config file")


@pytest.mark.parametrize("key, value", [("mean", float("nan")), ("std", float("inf"))])
def test_non_finite_distribution_values_name_the_key(tmp_path, key, value):
    raw = _surrogate_raw()
    raw["parameters"][0]["distribution"][key] = value
    name = raw["parameters"][0]["name"]
    assert_clean_error(invoke("check", write_config(tmp_path, raw)),
                       f"parameters[0] ({name}).distribution", "finite number")


@pytest.mark.parametrize("value", [1e6, -273.0])
def test_an_implausible_setpoint_names_the_test(tmp_path, value):
    raw = _surrogate_raw()
    raw["model"]["tests"][0]["setpoint_c"] = value
    assert_clean_error(invoke("check", write_config(tmp_path, raw)),
                       "model.tests[0] (H-ST).setpoint_c")


def test_a_non_finite_truth_value_names_the_key(tmp_path):
    config = write_config(tmp_path, _surrogate_raw())
    truth = tmp_path / "truth.yaml"
    name = _surrogate_raw()["parameters"][0]["name"]
    truth.write_text(yaml.safe_dump({"values": {name: float("nan")}}))
    assert_clean_error(invoke("synth", config, "--truth", truth), str(truth), f"values.{name}",
                       "finite number")
    assert not (tmp_path / "run" / "truth").exists()


def test_a_repeated_yaml_key_is_refused_naming_it(tmp_path):
    config = write_config(tmp_path, _surrogate_raw())
    config.write_text(config.read_text() + "design:\n  method: lhs\n  samples: 7\n")
    assert_clean_error(invoke("check", config), str(config), "'design' appears twice")


def test_a_test_longer_than_a_year_is_refused_before_dates_overflow(tmp_path):
    raw = _surrogate_raw()
    raw["model"]["tests"][0]["days"] = 1_000_000_000
    assert_clean_error(invoke("check", write_config(tmp_path, raw)), "model.tests[0] (H-ST).days")


def test_a_name_too_long_for_a_file_name_is_refused_by_check(tmp_path):
    raw = _surrogate_raw()
    raw["model"]["tests"][0]["name"] = "a" * 300
    assert_clean_error(invoke("check", write_config(tmp_path, raw)), "model.tests[0]",
                       "at most 100")


def test_timesteps_per_hour_must_divide_the_hour(tmp_path):
    raw = _surrogate_raw()
    raw["model"]["timesteps_per_hour"] = 7
    assert_clean_error(invoke("check", write_config(tmp_path, raw)), "model.timesteps_per_hour")


@pytest.mark.parametrize("content, needle", [
    ("seed: -5\n", "seed"),
    ("values:\n  ground_reflectance: 5.0\n", "ground_reflectance"),
])
def test_a_truth_outside_its_range_is_refused_before_anything_is_written(tmp_path, content,
                                                                         needle):
    config = write_config(tmp_path, _surrogate_raw())
    truth = tmp_path / "truth.yaml"
    truth.write_text(content)
    assert_clean_error(invoke("synth", config, "--truth", truth, "--out", tmp_path / "out"),
                       needle)
    assert not (tmp_path / "out" / "measured.csv").exists()


def test_a_weather_error_beyond_the_epw_range_is_refused_by_check(tmp_path):
    """A dry-bulb sensor error of +80 °C (a unit slip) would run: EnergyPlus only warns."""
    raw = _surrogate_raw()
    entry = next(p for p in raw["parameters"]
                 if any(t.get("weather") == "dry_bulb_temperature" for t in p["targets"]))
    entry["distribution"] = {"type": "uniform", "lower": 79.0, "upper": 81.0}
    entry["mode"] = "additive"
    assert_clean_error(invoke("check", write_config(tmp_path, raw)),
                       f"parameters ({entry['name']})", "dry_bulb_temperature", "-70..70 °C")


def test_a_truth_weather_error_beyond_the_epw_range_is_refused_by_synth(tmp_path):
    """A true dry-bulb error of 1000 °C made a 100 °C zone; the design's own check refuses it."""
    raw = _surrogate_raw()
    entry = next(p for p in raw["parameters"]
                 if any(t.get("weather") == "dry_bulb_temperature" for t in p["targets"]))
    config = write_config(tmp_path, raw)
    truth = tmp_path / "truth.yaml"
    truth.write_text(f"values:\n  {entry['name']}: 1000\n")
    assert_clean_error(invoke("synth", config, "--truth", truth, "--out", tmp_path / "out"),
                       f"parameters ({entry['name']})", "the truth values", "-70..70 °C")
    assert not (tmp_path / "out" / "measured.csv").exists()


def test_a_free_floating_test_with_a_setpoint_is_refused(tmp_path):
    raw = _surrogate_raw()
    raw["model"]["tests"][1]["setpoint_c"] = 21.0
    assert_clean_error(invoke("check", write_config(tmp_path, raw)),
                       "model.tests[1] (H-FF)", "free_floating", "no setpoint_c")


def test_february_29_is_a_day_of_a_leap_model_year(tmp_path):
    from bpsflow.config import load_config

    raw = _surrogate_raw()
    raw["model"]["year"] = 2024
    raw["model"]["periods"] = [{"name": "winter", "start": "02-27", "end": "03-03"}]
    for test, start in zip(raw["model"]["tests"], ("02-29", "03-02")):
        test["start"] = start
        test["days"] = 2
    config = load_config(write_config(tmp_path, raw))
    assert config.model.year == 2024
    raw["model"]["year"] = 2025
    assert_clean_error(invoke("check", write_config(tmp_path, raw)), "02-29",
                       "2025 is not a leap year")


@pytest.mark.parametrize("child, needle", [
    ({"extends": ["base.yaml"]}, "expected the path of one base config"),
    ({"extends": "."}, "is a folder"),
    ({"extends": "base.yaml", "parameters": []}, "removes nothing"),
    ({"extends": "base.yaml", "outputs": {}}, "outputs: an empty mapping"),
    ({"extends": "base.yaml", "model": {"boundary": {"surfaces": {}}}},
     "model.boundary.surfaces: an empty mapping"),
])
def test_extends_mistakes_are_named(tmp_path, child, needle):
    write_config(tmp_path, _surrogate_raw(), name="base.yaml")
    path = tmp_path / "child.yaml"
    path.write_text(yaml.safe_dump(child))
    assert_clean_error(invoke("check", path), str(path), needle)


def test_an_absolute_parameter_that_replaces_another_on_the_same_field_is_refused(tmp_path):
    """Two parameters on one field: a later absolute one makes the first do nothing (its
    Morris mu* came out 0), so check refuses the pair, naming both."""
    raw = _surrogate_raw()
    first = next(p for p in raw["parameters"]
                 if p["mode"] == "relative" and "object" in p["targets"][0])
    raw["parameters"].append({"name": "replacing_value", "mode": "absolute",
                              "distribution": {"type": "uniform", "lower": 0.02, "upper": 0.04},
                              "targets": [dict(first["targets"][0])]})
    assert_clean_error(invoke("check", write_config(tmp_path, raw)),
                       first["name"], "replacing_value (absolute)", "no effect")


def test_tests_under_other_control_may_not_share_a_day(tmp_path):
    """A day has one setpoint schedule: a later free-floating test once left the heating
    test's last day floating, and its heating output read 0 W without a word."""
    raw = _surrogate_raw()
    raw["model"]["tests"][1]["start"] = "12-06"
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "model.tests[1] (H-FF)", "overlap test H-ST's 12-05..12-06",
                       "mode heating vs free_floating")
    same = _surrogate_raw()
    same["model"]["tests"][1].update(start="12-06", **{k: same["model"]["tests"][0][k]
                                                       for k in ("mode", "setpoint_c",
                                                                 "setback_c")})
    (tmp_path / "same").mkdir()
    result = invoke("check", write_config(tmp_path / "same", same), "--no-run")
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("mode,setpoint,setback,needle", [
    ("heating", 21.0, 25.0, "is above setpoint_c (21 °C) of a heating test"),
    ("cooling", 26.0, 20.0, "is below setpoint_c (26 °C) of a cooling test")])
def test_a_setback_on_the_wrong_side_of_the_setpoint_is_refused(tmp_path, mode, setpoint,
                                                                setback, needle):
    raw = _surrogate_raw()
    raw["model"]["tests"][0].update(mode=mode, setpoint_c=setpoint, setback_c=setback)
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "model.tests", "setback_c", needle)


@pytest.mark.parametrize("start,end", [(8, 8), (24, 0), (0, 24)])
def test_an_empty_setback_window_is_refused(tmp_path, start, end):
    raw = _surrogate_raw()
    raw["model"]["tests"][0].update(mode="heating", setpoint_c=21.0, setback_c=15.0,
                                    setback_start_hour=start, setback_end_hour=end)
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "model.tests", "setback window is empty")


def test_an_output_listed_twice_in_a_test_is_refused(tmp_path):
    raw = _surrogate_raw()
    output = raw["model"]["tests"][0]["outputs"][0]
    raw["model"]["tests"][0]["outputs"] = [output, output]
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "model.tests", "outputs", "appears more than once")


def test_an_odd_number_of_morris_levels_is_refused(tmp_path):
    raw = _surrogate_raw()
    raw["design"] = {"method": "morris", "levels": 3, "trajectories": 2}
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "design.levels", "even number of levels")


@pytest.mark.parametrize("year", [0, -5, 99999])
def test_an_impossible_model_year_names_the_key(tmp_path, year):
    raw = _surrogate_raw()
    raw["model"]["year"] = year
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"), "model.year")


@pytest.mark.parametrize("mode, distribution", [
    ("additive", {"type": "uniform", "lower": -50.0, "upper": -40.0}),
    ("relative", {"type": "uniform", "lower": -2.0, "upper": -1.0}),
])
def test_a_weather_perturbation_that_removes_the_quantity_is_refused(tmp_path, mode,
                                                                     distribution):
    """Clipping at zero is for an offset in calm hours; taking every hour to 0 is a mistake."""
    raw = _surrogate_raw()
    raw["parameters"].append({"name": "wind_error", "mode": mode, "distribution": distribution,
                              "targets": [{"weather": "wind_speed"}]})
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "wind_error)", "wind_speed", "clipped to 0")


def test_thermostat_zones_are_checked_on_the_surrogate_too(tmp_path):
    raw = _surrogate_raw()
    raw["model"]["thermostat_zones"] = ["NoZone"]
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "model.thermostat_zones[0]", "'NoZone' is not a zone")


def test_boundary_temperatures_in_kelvin_are_refused(tmp_path):
    import pandas as pd

    from conftest import ROOT

    frame = pd.read_csv(ROOT / "sample_idf" / "boundary_temperatures.csv")
    columns = [c for c in frame.columns if c.endswith("_c")]
    frame[columns] = frame[columns] + 273.15
    path = tmp_path / "kelvin.csv"
    frame.to_csv(path, index=False)
    raw = _surrogate_raw()
    raw["model"]["boundary"]["file"] = str(path)
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"), "kelvin.csv",
                       "model.boundary.file", "kelvin in a °C column?")


def test_an_output_key_that_names_nothing_in_the_model_is_refused_by_check(tmp_path):
    raw = _surrogate_raw()
    raw["outputs"]["zone_air_temperature_c"]["key"] = "Cel"
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "outputs.zone_air_temperature_c.key", "'Cel' names nothing in the model",
                       "did you mean 'Cell'")


def test_a_truth_beyond_the_prior_is_said_not_refused(tmp_path):
    raw = _surrogate_raw()
    parameter = next(p for p in raw["parameters"] if p["distribution"]["type"] == "normal"
                     and "upper" in p["distribution"])
    config = write_config(tmp_path, raw)
    truth = tmp_path / "truth.yaml"
    truth.write_text(yaml.safe_dump({"seed": 1, "values": {
        parameter["name"]: parameter["distribution"]["upper"] + 1.0}}))
    result = invoke("synth", config, "--truth", truth)
    assert result.exit_code == 0, result.output
    flat = " ".join((result.output + getattr(result, "stderr", "")).split())
    assert f"values.{parameter['name']}" in flat and "cannot cover it" in flat


@pytest.mark.parametrize("section, needle", [
    ({"outputs": ["heating_power_w", "heating_power_w"]}, "outputs: heating_power_w listed more"),
    ({"outputs": []}, "the list is empty"),
    ({"parameters": []}, "the list is empty"),
])
def test_calibration_lists_repeated_or_empty_are_named(tmp_path, section, needle):
    raw = _surrogate_raw()
    raw["calibration"] = section
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"), needle)


def test_a_diagnosis_extension_listed_twice_is_refused(tmp_path):
    raw = _surrogate_raw()
    raw["diagnosis"] = {"extensions": ["infiltration", "infiltration"]}
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "extensions: infiltration listed more than once")


def test_a_simulation_change_names_the_innermost_key():
    from bpsflow.design_record import changed_keys

    before = {"model.tests": [{"name": "H", "setpoint_c": 30.0, "days": 2}],
              "outputs.heat": {"key": "Cell", "scale": 1.0}}
    after = {"model.tests": [{"name": "H", "setpoint_c": 28.0, "days": 2}],
             "outputs.heat": {"key": "Zone", "scale": 1.0}}
    assert changed_keys(before, after) == ["model.tests[0].setpoint_c: 30.0 -> 28.0",
                                           "outputs.heat.key: Cell -> Zone"]


@pytest.mark.parametrize("where", ["design.samples", "calibration.bayes.chains",
                                   "distribution.lower", "truth"])
def test_true_or_false_for_a_number_is_refused_naming_the_key(tmp_path, where):
    # pydantic's lax mode reads true as 1 and false as 0.0: a YAML yes/on would pass as a number
    raw = _surrogate_raw()
    truth_args: list = []
    if where == "design.samples":
        raw["design"]["samples"] = True
        expected = ["design: samples", "whole number"]
    elif where == "calibration.bayes.chains":
        raw["calibration"] = {"bayes": {"chains": True}}
        expected = ["calibration", "chains", "whole number"]
    elif where == "distribution.lower":
        first = next(p for p in raw["parameters"] if p["distribution"]["type"] == "uniform")
        first["distribution"]["lower"] = False
        expected = ["distribution", "lower", "a number"]
    else:
        name = raw["parameters"][0]["name"]
        truth = tmp_path / "truth.yaml"
        truth.write_text(yaml.safe_dump({"values": {name: True}}))
        truth_args = ["--truth", truth]
        expected = [str(truth), "values", "a mapping to a number"]
    config = write_config(tmp_path, raw)
    command = ("synth", config, *truth_args) if truth_args else ("check", config, "--no-run")
    assert_clean_error(invoke(*command), *expected, "true/false")


@pytest.mark.parametrize("section, expected", [
    ({"zone": "NoSuchZone"}, "diagnosis.zone: 'NoSuchZone' is not a Zone of the model"),
    ({"extension_zones": {"internal_gain_schedule": "Lab"}},
     "diagnosis.extension_zones.internal_gain_schedule: 'Lab' is not a Zone"),
    ({"output": "lab_heating_w"}, "diagnosis.output: 'lab_heating_w' is not an output"),
    ({"extensions": ["infiltration"], "extension_zones": {"thermal_mass": "Cell"}},
     "extension_zones: thermal_mass is not in extensions"),
    ({"parameters": ["no_such_input"]}, "diagnosis.parameters[0]: 'no_such_input'")])
def test_check_refuses_what_diagnose_would_refuse(tmp_path, section, expected):
    """check said 'config is valid' and diagnose then refused the same config."""
    raw = _surrogate_raw()
    raw["diagnosis"] = section
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"), expected)


def test_an_empty_snippet_list_over_a_base_with_snippets_is_named():
    from bpsflow.config import _empty_merges

    base = {"model": {"idf_objects": ["/a/leak.idf"], "idf": "/a/m.idf"}, "outputs": {"x": {}}}
    assert _empty_merges(base, {"model": {"idf_objects": []}}) == ["model.idf_objects"]
    # a list that replaces (diagnosis.parameters) and an empty mapping over an empty one change
    # what they say, or nothing the base had: not named
    assert _empty_merges({"diagnosis": {"parameters": ["a"]}, "outputs": {}},
                         {"diagnosis": {"parameters": []}, "outputs": {}}) == []


@pytest.mark.parametrize("calibration, needle", [
    ({"outputs": ["foo"]}, "calibration.outputs[0]: unknown output 'foo'"),
    ({"parameters": ["foo"]}, "'foo' is not a parameter"),
    ({"holdout_days": 40}, "calibration.holdout_days"),
    ({"scenarios": [{"name": "A", "outputs": ["foo"], "resolution": "daily"}]},
     "calibration.scenarios (A).outputs[0]"),
    # no held-out design runs: the emulator error term would be dropped without a word
    ({"emulator": {"test_fraction": 0}}, "emulator.test_fraction: 0 holds out no design runs"),
    ({"variable_inputs": []}, "variable_inputs: the list is empty"),
])
def test_check_refuses_what_calibrate_would(tmp_path, calibration, needle):
    raw = _surrogate_raw()
    fitted = next(p["name"] for p in raw["parameters"]
                  if p["distribution"]["type"] in ("uniform", "normal", "beta", "triangular"))
    raw["model"]["tests"][0]["warmup_days"] = 0     # two evaluated days: one held out
    fine = {"parameters": [fitted], "holdout_days": 1, "resolution": "hourly",
            "outputs": ["heating_power_w"]}
    raw["calibration"] = {**fine, **calibration}
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"), needle)
    raw["calibration"] = fine
    (tmp_path / "fine").mkdir()
    assert invoke("check", write_config(tmp_path / "fine", raw), "--no-run").exit_code == 0


def test_a_truth_that_is_a_folder_is_named_as_such(tmp_path):
    config = write_config(tmp_path, _surrogate_raw())
    (tmp_path / "truths").mkdir()
    assert_clean_error(invoke("synth", config, "--truth", tmp_path / "truths"),
                       "is not a file; expected a YAML truth file")
    assert_clean_error(invoke("synth", config, "--truth", tmp_path / "none.yaml"),
                       "file not found; expected a YAML truth file")


def test_an_output_scale_of_zero_is_refused(tmp_path):
    raw = _surrogate_raw()
    name = next(iter(raw["outputs"]))
    raw["outputs"][name]["scale"] = 0
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       f"outputs.{name}", "scale: 0")


def test_yaml_merge_keys_are_read_and_repeated_keys_still_refused():
    from bpsflow.config import parse_yaml

    assert parse_yaml("base: &b {a: 1, b: 2}\nx:\n  <<: *b\n  b: 3\n")["x"] == {"a": 1, "b": 3}
    with pytest.raises(yaml.YAMLError, match="appears twice"):
        parse_yaml("x: {a: 1, a: 2}\n")


def test_an_output_named_timestamp_is_refused(tmp_path):
    raw = _surrogate_raw()
    raw["outputs"]["timestamp"] = raw["outputs"].pop("heating_power_w")
    for test in raw["model"]["tests"]:
        test["outputs"] = ["timestamp" if o == "heating_power_w" else o for o in test["outputs"]]
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "output name 'timestamp'", "time column")


def test_truth_values_a_design_cannot_draw_are_said(tmp_path):
    from bpsflow.config import load_config
    from bpsflow.synth import Truth, truth_notes

    raw = _surrogate_raw()
    raw["parameters"][0]["distribution"] = {"type": "constant", "value": 1.0}
    raw["parameters"][1]["distribution"] = {"type": "discrete", "values": [0.9, 1.0, 1.1]}
    config = load_config(write_config(tmp_path, raw))
    first, second = raw["parameters"][0]["name"], raw["parameters"][1]["name"]
    notes = truth_notes(config, Truth(values={first: 1.2, second: 1.05}))
    assert any(first in n and "replaces the constant 1" in n for n in notes)
    assert any(second in n and "none of its distribution's values" in n for n in notes)
    assert truth_notes(config, Truth(values={first: 1.0, second: 1.1})) == []


def test_a_period_no_test_uses_is_noted_by_check(tmp_path):
    raw = _surrogate_raw()
    raw["model"]["periods"].append({"name": "spare", "start": "03-01", "end": "03-07"})
    result = invoke("check", write_config(tmp_path, raw), "--no-run")
    assert result.exit_code == 0
    assert "'spare' is the period of no test" in " ".join(result.output.split())
