"""Bad-input battery: model inputs are checked the same on every backend, before anything runs.

Classes (issue "Hardening"): command-line overrides go through the schema
(with bounds, the design size capped); IDF targets are IDD fields whose values
stay within the IDD bounds (and glazing T + R < 1) on every backend, for the
distributions (``check``) and the drawn samples (``sample``, ``run``); the
weather file is parsed fully; ``idf_objects`` snippets and the IDF must be IDF
objects of known types, refused without echoing their content; other model
files (boundary data) give one clear error naming the file. Each case goes
through the CLI and asserts exit 2, the file and key (and line) in the
message, no traceback, and, where a previous run exists, that it is
byte-identical afterwards.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from battery import assert_clean_error, assert_ok, assert_unchanged, invoke, snapshot

from bpsflow.config import MAX_DESIGN_RUNS, load_config

from conftest import ROOT, short_raw, write_config

CONDUCTIVITY = {"object": "Material", "name": "SouthWallInsulation", "field": "Conductivity"}


def surrogate_raw(samples: int = 3) -> dict:
    raw = short_raw(samples=samples)
    raw["model"]["backend"] = "surrogate"
    return raw


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished surrogate run (sample + run): the results every refusal must leave alone."""
    folder = tmp_path_factory.mktemp("finished")
    config = write_config(folder, surrogate_raw())
    assert_ok(invoke("run", config, "--no-progress"))
    assert (folder / "run" / "results.parquet").is_file()
    return folder


def variant(finished: Path, tmp_path: Path, change) -> Path:
    """A config running in the finished run's directory, changed by ``change(raw)``."""
    raw = surrogate_raw()
    change(raw)
    path = write_config(tmp_path, raw)
    text = path.read_text().replace(str(tmp_path / "run"), str(finished / "run"))
    path.write_text(text)
    return path


# 1. Command-line overrides go through the schema --------------------------------------

@pytest.mark.parametrize("args, needles", [
    (["--samples", "0"], ["--samples (design.samples)", "greater than or equal to 2"]),
    (["--samples", "-5"], ["--samples (design.samples)", "greater than or equal to 2"]),
    (["--samples", "10000000"], ["--samples (design.samples)",
                                 f"less than or equal to {MAX_DESIGN_RUNS}"]),
    (["--seed", "-1"], ["--seed (design.seed)", "greater than or equal to 0"]),
    (["--samples", "0", "--force"], ["--samples (design.samples)"]),
])
def test_sample_override_out_of_bounds_is_refused_before_anything_changes(finished, args,
                                                                          needles):
    config = finished / "case.yaml"
    before = snapshot(finished / "run")
    result = invoke("sample", config, *args)
    assert_clean_error(result, str(config), *needles)
    assert_unchanged(before, finished / "run")


@pytest.mark.parametrize("command, args, needles", [
    ("run", ["--jobs", "0"], ["--jobs (execution.jobs)", "greater than or equal to 1"]),
    ("run", ["--jobs", "100000"], ["--jobs (execution.jobs)", "less than or equal to 1024"]),
    ("validate", ["--q", "1.5", "--measured", "nowhere.csv"], ["--q (validation.q)",
                                                                "less than 1"]),
    ("sensitivity", ["--trajectories", "1"], ["--trajectories (design.trajectories)"]),
    ("sensitivity", ["--levels", "1"], ["--levels (design.levels)"]),
    ("sensitivity", ["--trajectories", "40000"], ["design.trajectories", "Morris runs",
                                                  str(MAX_DESIGN_RUNS)]),
    ("calibrate", ["--measured", "nowhere.csv", "--chains", "0"],
     ["--chains (calibration.bayes.chains)"]),
    ("calibrate", ["--measured", "nowhere.csv", "--runs", "10000000"],
     ["--runs (calibration.design.runs)", "less than or equal to"]),
    ("diagnose", ["--measured", "nowhere.csv", "--jobs", "-2"], ["--jobs (execution.jobs)"]),
])
def test_numeric_overrides_name_option_key_and_bound(finished, command, args, needles):
    config = finished / "case.yaml"
    before = snapshot(finished / "run")
    result = invoke(command, config, *args)
    assert_clean_error(result, str(config), *needles)
    assert_unchanged(before, finished / "run")


def test_design_size_cap_in_the_file_is_refused(tmp_path):
    raw = surrogate_raw()
    raw["design"]["samples"] = MAX_DESIGN_RUNS + 1
    config = write_config(tmp_path, raw)
    assert_clean_error(invoke("check", config), str(config), "design.samples",
                       f"less than or equal to {MAX_DESIGN_RUNS}")


# 2. IDF targets: IDD fields, IDD bounds, glazing sums, on every backend ------------------

def _misspelt(raw):
    raw["parameters"][0]["targets"][0]["field"] = "Conductivty"


def _negative_conductivity(raw):
    raw["parameters"].append({"name": "k_absolute", "mode": "absolute",
                              "distribution": {"type": "uniform", "lower": -0.1, "upper": 0.1},
                              "targets": [dict(CONDUCTIVITY)]})


def _glazing_sum(raw):
    raw["parameters"].append({
        "name": "transmittance_high", "mode": "absolute",
        "distribution": {"type": "uniform", "lower": 0.8, "upper": 0.95},
        "targets": [{"object": "WindowMaterial:Glazing", "name": "ClearGlass3mm",
                     "field": "Solar Transmittance at Normal Incidence"}]})


def _unbounded_tail(raw):
    # Normal without bounds: its far tail (what a Latin hypercube can draw) is negative.
    raw["parameters"].append({"name": "k_normal", "mode": "absolute",
                              "distribution": {"type": "normal", "mean": 0.04, "std": 0.01},
                              "targets": [dict(CONDUCTIVITY)]})


@pytest.mark.parametrize("change, needles", [
    (_misspelt, ["parameters[0]", "targets[0].field", "no field 'Conductivty'", "Conductivity"]),
    (_negative_conductivity, ["k_absolute", "Material 'SouthWallInsulation'",
                              "field 'Conductivity'", "-0.1", "> 0"]),
    (_glazing_sum, ["transmittance_high", "WindowMaterial:Glazing 'ClearGlass3mm'",
                    "'Solar Transmittance at Normal Incidence' + 'Front Side Solar Reflectance",
                    "< 1"]),
    (_unbounded_tail, ["k_normal", "field 'Conductivity'", "> 0"]),
])
@pytest.mark.parametrize("command", ["check", "run", "sample"])
def test_idd_targets_refused_on_the_surrogate_before_running(finished, tmp_path, change, needles,
                                                             command):
    config = variant(finished, tmp_path, change)
    before = snapshot(finished / "run")
    args = ["--no-progress"] if command == "run" else ["--force"] if command == "sample" else []
    result = invoke(command, config, *args)
    text = assert_clean_error(result, str(config), *needles)
    assert "config is valid" not in text
    assert_unchanged(before, finished / "run")


def test_drawn_sample_outside_the_idd_bounds_names_the_instance(tmp_path):
    """samples.parquet edited (or drawn under another config): the first bad instance is named."""
    raw = surrogate_raw()
    config = write_config(tmp_path, raw)
    assert_ok(invoke("sample", config))
    samples_path = tmp_path / "run" / "samples.parquet"
    samples = pd.read_parquet(samples_path)
    name = next(p["name"] for p in raw["parameters"] if CONDUCTIVITY in p["targets"])
    samples.loc[samples["instance"] == 1, name] = -2.0  # a relative multiplier below zero
    samples.to_parquet(samples_path, index=False)
    before = snapshot(tmp_path / "run")
    result = invoke("run", config, "--no-progress")
    assert_clean_error(result, str(config), "instance 1", f"{name} = -2",
                       "Material 'SouthWallInsulation' field 'Conductivity'", "> 0")
    assert_unchanged(before, tmp_path / "run")
    assert not (tmp_path / "run" / "instances").exists()


@pytest.mark.energyplus
def test_idd_bounds_refused_before_energyplus_runs(tmp_path):
    raw = short_raw(samples=2)
    raw["model"]["backend"] = "energyplus"
    _negative_conductivity(raw)
    config = write_config(tmp_path, raw)
    for command in ("check", "run"):
        result = invoke(command, config, *(["--no-progress"] if command == "run" else []))
        assert_clean_error(result, str(config), "k_absolute", "field 'Conductivity'", "> 0")
    run_dir = tmp_path / "run"
    assert not (run_dir / "instances").exists()
    assert not (run_dir / "samples.parquet").exists()


# 3. The weather file is parsed fully ------------------------------------------------------

def _epw_lines() -> list[str]:
    return load_config(ROOT / "configs" / "i600.yaml").model.weather.read_text().splitlines()


def _set_field(lines, line, field, value):
    row = lines[line - 1].split(",")
    row[field - 1] = value
    lines[line - 1] = ",".join(row)
    return lines


BROKEN_WEATHER = {
    "empty": (lambda lines: b"", ["is empty"]),
    "binary": (lambda lines: bytes(range(256)) * 40, ["binary content"]),
    "truncated": (lambda lines: lines[:8 + 5000], ["found 5000", "8760 or 8784"]),
    "short_row": (lambda lines: lines[:99] + [",".join(lines[99].split(",")[:20])] + lines[100:],
                  ["line 100", "20 comma-separated fields", "35"]),
    "not_a_number": (lambda lines: _set_field(lines, 200, 7, "warm"),
                     ["line 200, field 7", "not a number"]),
    "header_short": (lambda lines: lines[:2] + lines[3:],
                     ["line 3", "TYPICAL/EXTREME PERIODS"]),
    "garbage_location": (lambda lines: ["LOCATION,somewhere,over,the,rainbow"] + lines[1:],
                         ["line 1", "LOCATION has 4 fields"]),
    "location_latitude": (lambda lines: _set_field(lines, 1, 7, "north"),
                          ["line 1, LOCATION field 7 (latitude)"]),
    "hours_swapped": (lambda lines: lines[:20] + [lines[21], lines[20]] + lines[22:],
                      ["line 21", "month/day/hour 1/1/14", "expected 1/1/13"]),
    "hour_duplicated": (lambda lines: lines[:20] + [lines[20], lines[20]] + lines[22:],
                        ["line 22", "expected 1/1/14"]),
    "dry_bulb_999": (lambda lines: _set_field(lines, 300, 7, "999"),
                     ["line 300, field 7 (dry_bulb_temperature)", "999", "-70..70"]),
    "missing_marker": (lambda lines: _set_field(lines, 301, 7, "99.9"),
                       ["line 301, field 7 (dry_bulb_temperature)", "missing-value marker"]),
    "negative_radiation": (lambda lines: _set_field(lines, 4000, 14, "-50"),
                           ["line 4000, field 14 (global_horizontal_radiation)", "-50"]),
    "csv": (lambda lines: ["timestamp,temperature"] + [f"2025-01-01 {h:02d}:00,{h}"
                                                      for h in range(24)],
            ["line 1", "LOCATION", "not an EPW weather file"]),
}


def _write_weather(folder: Path, name: str) -> Path:
    build, _ = BROKEN_WEATHER[name]
    content = build(_epw_lines())
    path = folder / f"{name}.epw"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text("\n".join(content) + "\n")
    return path


@pytest.mark.parametrize("name", sorted(BROKEN_WEATHER))
def test_check_refuses_broken_weather_naming_file_line_and_field(tmp_path, name):
    weather = _write_weather(tmp_path, name)
    raw = surrogate_raw()
    raw["model"]["weather"] = str(weather)
    config = write_config(tmp_path, raw)
    text = assert_clean_error(invoke("check", config), str(weather), "model.weather",
                              *BROKEN_WEATHER[name][1])
    assert "config is valid" not in text


@pytest.mark.parametrize("name", ["truncated", "hours_swapped", "dry_bulb_999"])
def test_run_refuses_broken_weather_and_keeps_the_results(finished, tmp_path, name):
    weather = _write_weather(tmp_path, name)
    config = variant(finished, tmp_path, lambda raw: raw["model"].update(weather=str(weather)))
    before = snapshot(finished / "run")
    result = invoke("run", config, "--no-progress", "--retry-failed")
    assert_clean_error(result, str(weather), "model.weather", *BROKEN_WEATHER[name][1])
    assert_unchanged(before, finished / "run")


# 4. idf_objects snippets are IDF objects of known types, never echoed ---------------------

SECRET = "hunter2-do-not-echo"


@pytest.mark.parametrize("content, needles", [
    (f"root:x:0:0:root:/root:/bin/bash\nadmin:{SECRET}:1000:1000::/home/admin:/bin/sh\n",
     ["line 1", "expected an IDF object: Type, field, ...;"]),
    (f"Material,\n  Wall, Rough, 0.1, 0.5, 800, 900;\n\n{SECRET} is here;\n",
     ["line 4", "expected an IDF object"]),
    ("Materal,\n  Wall, Rough, 0.1, 0.5, 800, 900;\n",
     ["line 1", "did you mean Material?"]),
    ("Material,\n  Wall, Rough, 0.1, 0.5, 800, 900\n", ["line 1", "never ends with ';'"]),
    ("! only a comment\n", ["no IDF objects"]),
])
@pytest.mark.parametrize("command", ["check", "run"])
def test_snippet_that_is_not_idf_objects_is_refused_without_echo(finished, tmp_path, content,
                                                                 needles, command):
    snippet = tmp_path / "snippet.idf"
    snippet.write_text(content)
    config = variant(finished, tmp_path,
                     lambda raw: raw["model"].update(idf_objects=[str(snippet)]))
    before = snapshot(finished / "run")
    result = invoke(command, config, *(["--no-progress"] if command == "run" else []))
    text = assert_clean_error(result, str(snippet), "model.idf_objects[0]", *needles)
    assert SECRET not in text and "/bin/bash" not in text
    assert_unchanged(before, finished / "run")


def test_valid_snippet_still_loads(tmp_path):
    snippet = tmp_path / "gain.idf"
    snippet.write_text("! an extra gain\nSchedule:Constant,\n  ExtraGainOn, , 1;\n")
    raw = surrogate_raw()
    raw["model"]["idf_objects"] = [str(snippet)]
    assert load_config(write_config(tmp_path, raw)).model.idf_objects == [snippet.resolve()]


# 5. Other malformed model files --------------------------------------------------------------

def _idf_text(raw, folder):
    path = folder / "model.idf"
    path.write_text("this is a text file,\nbut not a model at all;\n")
    raw["model"]["idf"] = str(path)
    return path


def _idf_binary(raw, folder):
    path = folder / "model.idf"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00" + bytes(range(256)))
    raw["model"]["idf"] = str(path)
    return path


def _boundary_missing(raw, folder):
    path = folder / "no_such_boundary.csv"
    raw["model"]["boundary"]["file"] = str(path)
    return path


def _boundary_text(raw, folder):
    source = Path(raw["model"]["boundary"]["file"])
    frame = pd.read_csv(source)
    column = next(c for c in frame.columns if c != "timestamp")
    frame[column] = frame[column].astype(object)
    frame.loc[41, column] = "sensor offline"
    path = folder / "boundary.csv"
    frame.to_csv(path, index=False)
    raw["model"]["boundary"]["file"] = str(path)
    return path


def _boundary_stamps(change):
    def edit(raw, folder):
        frame = pd.read_csv(Path(raw["model"]["boundary"]["file"]))
        path = folder / "boundary.csv"
        change(frame).to_csv(path, index=False)
        raw["model"]["boundary"]["file"] = str(path)
        return path
    return edit


def _reversed(frame):
    return frame.iloc[::-1]


def _hour_beginning(frame):
    stamps = pd.date_range("2025-01-01 00:00", periods=len(frame), freq="h")
    return frame.assign(timestamp=stamps.strftime("%m/%d %H:%M"))


@pytest.mark.parametrize("change, needles", [
    (_idf_text, ["model.idf", "line 1", "expected an IDF object"]),
    (_boundary_stamps(_reversed), ["column 'timestamp', row 2", "'12/31 24:00'",
                                   "expected '01/01 01:00'", "not the year's hours in order"]),
    (_boundary_stamps(_hour_beginning), ["row 2", "'01/01 00:00'", "hour-ending"]),
    (_idf_binary, ["model.idf", "binary content"]),
    (_boundary_missing, ["model.boundary.file", "not found"]),
    (_boundary_text, ["row 43"]),
])
@pytest.mark.parametrize("command", ["check", "run"])
def test_malformed_model_file_gives_one_clear_error(finished, tmp_path, change, needles, command):
    holder: dict[str, Path] = {}
    config = variant(finished, tmp_path, lambda raw: holder.setdefault("path",
                                                                       change(raw, tmp_path)))
    before = snapshot(finished / "run")
    result = invoke(command, config, *(["--no-progress"] if command == "run" else []))
    text = assert_clean_error(result, holder["path"].name, *needles)
    assert "config is valid" not in text
    assert_unchanged(before, finished / "run")


def test_shipped_configs_pass_the_model_input_checks():
    """Every shipped config keeps loading and passes the IDD-bound and weather checks."""
    from bpsflow.sampling import sample
    from bpsflow.simulation.model_inputs import check_model_inputs
    from bpsflow.simulation.target_bounds import check_sample_values

    for name in ("i600", "calibration", "diagnosis", "office3zone", "office3zone_hidden",
                 "office3zone_diagnosis"):
        config = load_config(ROOT / "configs" / f"{name}.yaml")
        check_model_inputs(config)
        check_sample_values(config, sample(config).values)


def test_field_limits_api():
    import numpy as np

    from bpsflow.simulation.field_limits import (
        UnknownFieldError,
        check_sums,
        check_value,
        clip_to_limits,
        field_limits,
    )

    limits = field_limits("MATERIAL", "conductivity")
    assert (limits.field, limits.minimum, limits.minimum_exclusive) == ("Conductivity", 0.0, True)
    assert check_value(limits, 0.0) and check_value(limits, -1) and not check_value(limits, 0.04)
    clipped = clip_to_limits(limits, np.array([-1.0, 0.5]))
    assert clipped[0] > 0 and clipped[1] == 0.5
    with pytest.raises(UnknownFieldError, match="no field 'Conductivty'"):
        field_limits("Material", "Conductivty")
    assert check_sums("WindowMaterial:Glazing", {"Solar Transmittance at Normal Incidence": 0.9,
                                                 "Front Side Solar Reflectance at Normal "
                                                 "Incidence": 0.1})
    assert not check_sums("WindowMaterial:Glazing", {
        "Solar Transmittance at Normal Incidence": 0.8,
        "Front Side Solar Reflectance at Normal Incidence": 0.1})


def test_bundled_idd_extract_matches_the_installed_idd():
    """The extract the surrogate reads is the EnergyPlus IDD's (regenerate it when they differ)."""
    from bpsflow.config import bundled_weather_dir
    from bpsflow.simulation.field_limits import object_fields, parse_idd

    folder = bundled_weather_dir()
    if folder is None or not (folder.parent / "Energy+.idd").is_file():
        pytest.skip("no EnergyPlus IDD installed")
    types = parse_idd((folder.parent / "Energy+.idd").read_text(errors="replace"))
    for key, (_, fields) in types.items():
        assert object_fields(key) == tuple(fields), key



def test_a_misspelt_output_names_the_closest_names_energyplus_reports(tmp_path):
    """A run that reported nothing for a typo'd meter says which names the model has."""
    import numpy as np

    from bpsflow.errors import BpsflowError
    from bpsflow.simulation.energyplus import tidy_outputs

    config = load_config(ROOT / "configs" / "i600.yaml")
    output = config.model.tests[0].outputs[0]
    spec = config.outputs[output].model_copy(update={"variable": None, "key": None,
                                                      "meter": "Heating:EnergyTransfr"})
    config.outputs[output] = spec
    header = "Program Version,EnergyPlus\nVar Type (reported time step),Var Report Type,Name\n"
    (tmp_path / "eplusout.mdd").write_text(
        header + "Zone,Meter,Heating:EnergyTransfer [J]\nZone,Meter,Electricity:Facility [J]\n")
    (tmp_path / "eplusout.rdd").write_text(header + "Zone,Average,Zone Mean Air Temperature [C]\n")
    # nothing reported at all: the columns have no string type
    empty = pd.DataFrame({"timestamp": np.array([], dtype="datetime64[ns]"),
                          "variable": np.array([], dtype=float), "key": np.array([], dtype=float),
                          "is_meter": np.array([], dtype=int), "frequency": np.array([], dtype=float),
                          "value": np.array([], dtype=float)})
    with pytest.raises(BpsflowError, match=r"outputs\.\w+ \(meter Heating:EnergyTransfr.*did you "
                                           r"mean 'Heating:EnergyTransfer'\?"):
        tidy_outputs(config, 0, empty, tmp_path)


def test_check_runs_the_nominal_model_and_quotes_energyplus_on_a_broken_reference(tmp_path):
    """A surface naming a construction the model lacks passes every static check; the
    nominal two-day run in check fails with EnergyPlus's own severe line, before a run."""
    raw = short_raw()
    source = Path(raw["model"]["idf"])
    text = source.read_text()
    line = "SouthWallConstruction,   !- Construction Name"
    assert line in text
    broken = text.replace(line, "NoSuchConstruction,   !- Construction Name", 1)
    raw["model"]["idf"] = str(tmp_path / "broken.idf")
    (tmp_path / "broken.idf").write_text(broken)
    config = write_config(tmp_path, raw)
    assert_clean_error(invoke("check", config), "does not run in EnergyPlus at its nominal",
                       "NOSUCHCONSTRUCTION")
    assert_ok(invoke("check", config, "--no-run"))
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("backend", ["surrogate", "energyplus"])
def test_a_missing_semicolon_is_pointed_at(tmp_path, backend):
    """Without an object's ';' the next object runs on as its fields: the error (a target
    that finds no object, or eppy's own) says where the ';' is probably missing."""
    raw = short_raw()
    raw["model"]["backend"] = backend
    text = Path(raw["model"]["idf"]).read_text()
    line = "    0.6;                     !- Visible Absorptance"
    assert line in text
    raw["model"]["idf"] = str(tmp_path / "broken.idf")
    (tmp_path / "broken.idf").write_text(text.replace(line, line.replace(";", ","), 1))
    assert_clean_error(invoke("check", write_config(tmp_path, raw)),
                       "Material 'SouthWallExteriorPanel'", "a missing ';'")


def test_a_model_that_ran_design_days_only_still_runs_the_tools_period(tmp_path):
    """Example files often switch weather-file run periods off; the tool's RunPeriod is the
    simulation, so it switches them on (outputs were empty and named as misspelt)."""
    raw = short_raw()
    text = Path(raw["model"]["idf"]).read_text()
    line = "    Yes,                     !- Run Simulation for Weather File Run Periods"
    assert line in text
    raw["model"]["idf"] = str(tmp_path / "design_days.idf")
    (tmp_path / "design_days.idf").write_text(text.replace(line, line.replace("Yes", "No "), 1))
    text = assert_ok(invoke("check", write_config(tmp_path, raw)))
    assert "the nominal model ran in EnergyPlus" in text


def test_a_parameter_on_a_setpoint_schedule_the_tests_replace_is_refused(tmp_path):
    """The tests' setpoints replace the thermostat's setpoint objects, so a parameter on
    the schedule only those read changed nothing (mu* = 0 without a word); it is refused."""
    raw = short_raw()
    raw["parameters"].append({
        "name": "model_heating_setpoint", "mode": "absolute",
        "distribution": {"type": "uniform", "lower": 19.0, "upper": 22.0},
        "targets": [{"object": "Schedule:Compact", "name": "HeatingSetpointSchedule",
                     "field": "Field 4"}]})
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "(model_heating_setpoint)", "HeatingSetpointSchedule",
                       "would change nothing", "mode: model")


def test_check_notes_a_relative_parameter_on_a_zero_field(tmp_path):
    """0 x factor stays 0: a relative parameter on a field the model leaves at 0 moves
    nothing there, and check says so (the shipped glazing's infrared transmittance is 0)."""
    raw = short_raw()
    raw["model"]["backend"] = "surrogate"
    names = [p["name"] for p in raw["parameters"]]
    assert "glazing_infrared_transmittance" in names
    text = assert_ok(invoke("check", write_config(tmp_path, raw)))
    flat = " ".join(text.split())
    assert "glazing_infrared_transmittance (relative) cannot move 1 field(s) whose model " \
           "value is 0" in flat
    assert "south_wall_insulation_conductivity (relative) cannot" not in flat


def test_a_wrong_key_of_a_known_variable_is_named_as_the_key(tmp_path):
    """EnergyPlus lists the variable in its .rdd but reports nothing for the key: the hint
    names the key, not a 'did you mean' the same variable."""
    import numpy as np
    import pandas as pd

    from bpsflow.config import OutputVariable
    from bpsflow.simulation.energyplus import _missing_output_hint

    (tmp_path / "eplusout.rdd").write_text(
        "Program Version,EnergyPlus\nVar Type (reported time step),Var Report Type,Variable "
        "Name [Units]\nZone,Average,Zone Mean Air Temperature [C]\n")
    spec = OutputVariable(variable="Zone Mean Air Temperature", key="SPACE9-1", unit="C")
    raw = pd.DataFrame({"key": pd.Series([], dtype=str)})
    hint = _missing_output_hint(spec, raw, np.array([], bool), np.array([], dtype=object),
                                tmp_path)
    assert "nothing for key 'SPACE9-1'" in hint and "did you mean" not in hint


def test_autosizing_under_the_tests_setpoints_is_said():
    from bpsflow.config import load_config
    from bpsflow.simulation.idf import parse_idf_text
    from bpsflow.simulation.setpoints import sizing_note

    from conftest import ROOT

    config = load_config(ROOT / "configs" / "i600.yaml")
    sized = parse_idf_text("Coil:Heating:Electric, Reheat, , 1.0, autosize, , ;\n")
    fixed = parse_idf_text("Coil:Heating:Electric, Reheat, , 1.0, 5000, , ;\n")
    note = sizing_note(config, sized)
    assert note is not None and "autosizes 1 field(s)" in note and "mode: model" in note
    assert sizing_note(config, fixed) is None
    own = config.model_copy(deep=True)
    for test in own.model.tests:
        test.mode, test.setpoint_c, test.setback_c = "model", None, None
    assert sizing_note(own, sized) is None


def test_the_tools_schedules_carry_type_limits():
    """EnergyPlus warns in every run of a schedule without limits."""
    from bpsflow.config import load_config
    from bpsflow.simulation.idf import parse_idf_text
    from bpsflow.simulation.setpoints import (
        CONTROL_TYPE_LIMITS,
        TEMPERATURE_LIMITS,
        control_objects_text,
        setpoint_schedules,
    )

    from conftest import ROOT

    config = load_config(ROOT / "configs" / "i600.yaml")
    heating, cooling = setpoint_schedules(config, config.model.periods[0])
    objects = parse_idf_text(heating + cooling + control_objects_text()).objects
    limits = {o.name for o in objects if o.type == "SCHEDULETYPELIMITS"}
    assert limits == {TEMPERATURE_LIMITS, CONTROL_TYPE_LIMITS}
    for schedule in (o for o in objects if o.type.startswith("SCHEDULE:")):
        assert schedule.fields[1] in limits, schedule.name


def test_help_shows_every_option_name_whole():
    """rich's two-column help cut --allow-unconverged to '--allow-unconverg…' at 80 columns."""
    from typer.testing import CliRunner

    from bpsflow.cli import app

    result = CliRunner().invoke(app, ["calibrate", "--help"], terminal_width=80)
    assert result.exit_code == 0
    assert "--allow-unconverged" in result.output and "…" not in result.output


@pytest.mark.parametrize("extra, named", [
    (["--scenarios", "--resolution", "hourly"], "--resolution: --scenarios"),
    (["--scenarios", "--outputs", "heating_power_w"], "--outputs: --scenarios"),
    (["--method", "deterministic", "--chains", "8"], "--method deterministic does not sample")])
def test_calibrate_options_that_would_be_ignored_are_refused(tmp_path, extra, named):
    """--scenarios ran each scenario as configured whatever --resolution said."""
    config = write_config(tmp_path, short_raw())
    result = invoke("calibrate", config, "--measured", tmp_path / "nowhere.csv", *extra)
    assert_clean_error(result, named)


def test_an_unknown_output_of_the_outputs_option_names_the_option(tmp_path):
    config = write_config(tmp_path, short_raw())
    result = invoke("calibrate", config, "--measured", tmp_path / "nowhere.csv",
                    "--outputs", "heating_powr_w")
    assert_clean_error(result, "--outputs: 'heating_powr_w' is not an output of the config")


@pytest.mark.parametrize("declared, scale, reported, passes", [
    ("W", 1.0, "W", True), ("°C", 1.0, "C", True), ("degC", 1.0, "C", True),
    ("W", 10.0, "W", True),                    # a multiplier, not a conversion
    ("kWh", 1 / 3.6e6, "J", True), ("kWh", -1 / 3.6e6, "J", True),
    ("kWh/m2", 1 / 3.6e6 / 120, "J", True),    # the user's own conversion
    ("", 1.0, "J", True), ("kWh", 1.0, "", True),
    ("kWh", 1.0, "J", False), ("kWh", 1e-3, "J", False), ("C", 1.0, "W", False),
    ("kW", 1.0, "W", False),
])
def test_declared_units_against_the_reported_unit(declared, scale, reported, passes):
    from bpsflow.units import unit_mismatch

    mismatch = unit_mismatch(declared, scale, reported)
    assert (mismatch is None) == passes
    if not passes:
        assert reported in mismatch and declared in mismatch


@pytest.mark.energyplus
def test_check_refuses_an_output_unit_energyplus_does_not_report(tmp_path):
    """A W variable declared kWh (scale 1) would be summed as energy when measured data are
    aggregated: check's trial run compares the declared unit with EnergyPlus's."""
    raw = short_raw()
    name = next(iter(raw["outputs"]))
    raw["outputs"][name]["unit"] = "kWh"
    assert_clean_error(invoke("check", write_config(tmp_path, raw)),
                       f"outputs.{name}.unit", "reports it in W, not kWh")


def test_a_field_reached_twice_by_one_relative_parameter_is_refused(tmp_path):
    """'*' plus the object's own name moved SouthWallInsulation by the factor squared."""
    raw = surrogate_raw()
    raw["parameters"].append({"name": "k_twice", "mode": "relative",
                              "distribution": {"type": "uniform", "lower": 0.9, "upper": 1.1},
                              "targets": [{**CONDUCTIVITY, "name": "*"}, dict(CONDUCTIVITY)]})
    raw["parameters"] = [p for p in raw["parameters"]
                         if p["name"] == "k_twice" or all(
                             t.get("field") != "Conductivity" for t in p["targets"])]
    config = write_config(tmp_path, raw)
    for command in ("check", "sample"):
        assert_clean_error(invoke(command, config), "(k_twice).targets[1]",
                           "Material 'SouthWallInsulation' Conductivity", "apply twice")


def test_a_model_with_two_objects_of_one_name_is_refused(tmp_path):
    """The surrogate used the second copy; EnergyPlus refuses the model."""
    raw = surrogate_raw()
    text = Path(raw["model"]["idf"]).read_text()
    raw["model"]["idf"] = str(tmp_path / "twice.idf")
    (tmp_path / "twice.idf").write_text(
        text + "\nMaterial, SouthWallInsulation, Rough, 0.01, 2.0, 30, 1400;\n")
    assert_clean_error(invoke("check", write_config(tmp_path, raw), "--no-run"),
                       "twice.idf", "Material 'SouthWallInsulation' is defined twice")


def test_name_patterns_never_select_the_objects_bpsflow_adds():
    from bpsflow.simulation.targets import TOOL_OBJECT_PREFIX, matches_name

    added = TOOL_OBJECT_PREFIX + "infiltration_v2"
    assert matches_name("*", "Office Infiltration") and not matches_name("*", added)
    assert not matches_name("*infiltration*", added)
    assert matches_name(TOOL_OBJECT_PREFIX + "*", added) and matches_name(added.upper(), added)


def test_iso_hour_ending_boundary_stamps_are_read():
    from bpsflow.boundary import check_hour_order

    stamps = pd.date_range("2025-01-01 01:00", periods=8760, freq="h")
    check_hour_order(list(stamps.strftime("%Y-%m-%d %H:%M")), Path("b.csv"), "timestamp")
    energyplus = [f"{s - pd.Timedelta(hours=1):%m/%d} 24:00" if s.hour == 0 else f"{s:%m/%d %H:%M}"
                  for s in stamps]
    check_hour_order(energyplus, Path("b.csv"), "timestamp")


def test_a_change_of_a_text_field_is_refused_alike_on_both_backends(tmp_path):
    """The surrogate used to say it 'cannot represent this model' and to install EnergyPlus."""
    for backend in ("surrogate", "energyplus"):
        raw = surrogate_raw()
        raw["model"]["backend"] = backend
        raw["parameters"][0]["targets"][0]["field"] = "Roughness"
        name = raw["parameters"][0]["name"]
        (tmp_path / backend).mkdir()
        result = invoke("check", write_config(tmp_path / backend, raw), "--no-run")
        assert_clean_error(result, f"({name})", "'Roughness'", "not a number")
        assert "cannot represent" not in result.output


def test_a_boundary_surface_on_a_missing_schedule_is_named_on_the_surrogate(tmp_path):
    raw = surrogate_raw()
    surface = next(iter(raw["model"]["boundary"]["surfaces"]))
    raw["model"]["boundary"]["surfaces"][surface]["schedule"] = "NoSuchSchedule"
    result = invoke("check", write_config(tmp_path, raw), "--no-run")
    assert_clean_error(result, f"model.boundary.surfaces.{surface}.schedule", "NoSuchSchedule")
    assert "cannot represent" not in result.output


@pytest.mark.energyplus
def test_an_additive_change_reaches_a_number_written_in_a_schedule(tmp_path):
    """Schedule:Compact holds its values as text ('0.5'): an additive parameter moves them."""
    snippet = tmp_path / "extra.idf"
    snippet.write_text("Schedule:Compact, ExtraFraction, , Through: 12/31, For: AllDays, "
                       "Until: 24:00, 0.5;\n")
    raw = short_raw(samples=2)
    raw["model"]["idf_objects"] = [str(snippet)]
    raw["parameters"].append({"name": "extra_fraction", "mode": "additive",
                              "distribution": {"type": "uniform", "lower": 0.1, "upper": 0.2},
                              "targets": [{"object": "Schedule:Compact", "name": "ExtraFraction",
                                           "field": "Field 4"}]})
    config = write_config(tmp_path, raw)
    assert_ok(invoke("sample", config))
    assert_ok(invoke("instances", config, "-i", "0"))
    samples = pd.read_parquet(tmp_path / "run" / "samples.parquet").set_index("instance")
    written = next((tmp_path / "run" / "inspect" / "000000").rglob("*.idf")).read_text()
    value = 0.5 + float(samples.loc[0, "extra_fraction"])
    assert "ExtraFraction" in written and f"{value:.10g}" in written


def test_the_variables_energyplus_lists_are_read_in_both_layouts(tmp_path):
    from bpsflow.simulation.energyplus import reported_names

    (tmp_path / "eplusout.rdd").write_text(
        "! Program Version,EnergyPlus, Version 25.2.0\n! Output:Variable Objects\n"
        "Output:Variable,*,Zone Unit Heater Heating Rate,hourly; !- HVAC Average [W]\n")
    (tmp_path / "eplusout.mdd").write_text(
        "Program Version,EnergyPlus, Version 25.2.0\nVar Type (reported time step),Var Report "
        "Type,Variable Name [Units]\nZone,Meter,Electricity:Facility [J]\n")
    assert reported_names(tmp_path) == (["Zone Unit Heater Heating Rate"],
                                        ["Electricity:Facility"])


def test_ventilation_limits_the_surrogate_cannot_honour_are_refused(tmp_path):
    """Ventilation only above 40 °C outdoors ran all the time on the surrogate (+193 W)."""
    snippet = tmp_path / "vent.idf"
    snippet.write_text("ZoneVentilation:DesignFlowRate, WarmVent, Cell, AlwaysOn, Flow/Zone, "
                       "0.01, , , , Natural, 0, 1, 1, 0, 0, 0, -100, , 100, , -100, , 40;\n")
    raw = surrogate_raw()
    raw["model"]["idf_objects"] = [str(snippet)]
    result = invoke("check", write_config(tmp_path, raw), "--no-run")
    assert_clean_error(result, "ZoneVentilation:DesignFlowRate 'WarmVent'",
                       "'Minimum Outdoor Temperature' is '40'")
