"""Bad measured data, through the CLI: one clear error (exit 2) or a stated correction.

Every case runs on a finished surrogate run (5 instances of the two-test short
config) whose ``validation.csv``/``validation.json`` already exist; a failing
command must leave them byte-identical. Beside the battery: 15-minute data of a
known hourly truth give the hourly truth's metrics (and the report says it
aggregated), energy columns are summed, timestep outputs keep their step.
"""

from __future__ import annotations

import gzip
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from battery import all_text, assert_clean_error, assert_ok, assert_unchanged, invoke, snapshot

from bpsflow.config import load_config
from bpsflow.measured import read_measured

from conftest import short_raw, write_config

HEATING = "heating_power_w"
AIR = "zone_air_temperature_c"


@dataclass
class Case:
    """A copy of the finished run: the config, its run directory, the hourly truth."""

    config: Path
    run_dir: Path
    hourly: pd.DataFrame          # synth's measured.csv (timestamp index)
    folder: Path

    def write(self, frame: pd.DataFrame, name: str = "measured.csv") -> Path:
        path = self.folder / name
        frame.to_csv(path, index_label="timestamp")
        return path

    def text(self, content: str | bytes, name: str = "measured.csv") -> Path:
        path = self.folder / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        return path

    def csv_lines(self) -> list[str]:
        """The hourly truth as CSV lines (header first)."""
        return self.hourly.to_csv(index_label="timestamp").splitlines()

    def validate(self, measured: Path, *extra: object):
        return invoke("validate", self.config, "--measured", measured, "--run-dir", self.run_dir,
                      *extra)

    def validation(self) -> dict:
        return json.loads((self.run_dir / "validation.json").read_text())


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A surrogate run, its synthetic measurements and a first validation (module-wide)."""
    folder = tmp_path_factory.mktemp("measured_base")
    raw = short_raw(samples=5)
    raw["model"]["backend"] = "surrogate"
    config = write_config(folder, raw)
    assert_ok(invoke("run", config, "--no-progress"))
    truth = folder / "truth.yaml"
    truth.write_text("seed: 3\nvalues: {}\n")
    assert_ok(invoke("synth", config, "--truth", truth))
    text = assert_ok(invoke("validate", config, "--measured",
                            folder / "run" / "truth" / "measured.csv"))
    # what the threshold is for is said (a reader once compared it with nMCRPS)
    assert "accepted as valid when its score is at most the threshold" in " ".join(text.split())
    return folder


@pytest.fixture
def case(finished, tmp_path) -> Case:
    run_dir = tmp_path / "run"
    shutil.copytree(finished / "run", run_dir)
    hourly = pd.read_csv(run_dir / "truth" / "measured.csv", parse_dates=["timestamp"],
                         index_col="timestamp")
    return Case(config=finished / "case.yaml", run_dir=run_dir, hourly=hourly, folder=tmp_path)


def _assert_fails_cleanly(case: Case, measured: Path, *needles: str, command: str = "validate",
                   extra: tuple = ()) -> str:
    """``command`` on ``measured`` exits 2 naming the file and needles; the run dir is intact."""
    before = snapshot(case.run_dir)
    assert "validation.json" in before and "validation.csv" in before
    if command == "validate":
        result = case.validate(measured, *extra)
    else:
        result = invoke(command, case.config, "--measured", measured, "--run-dir", case.run_dir,
                        *extra)
    text = assert_clean_error(result, measured.name, *needles)
    assert_unchanged(before, case.run_dir)
    assert set(snapshot(case.run_dir)) == set(before), "a failing command wrote files"
    return text


def _metrics(case: Case) -> dict[tuple[str, str], dict]:
    return {(t["test"], t["output"]): t for t in case.validation()["tests"]}


def _assert_same_metrics(a: dict, b: dict, rel: float = 1e-9) -> None:
    assert a.keys() == b.keys()
    for key in a:
        for metric in ("threshold", "nmbe", "cv_rmse", "nmcrps", "mbe_c", "rmse_c", "mcrps_c"):
            if metric in a[key]:
                assert b[key][metric] == pytest.approx(a[key][metric], rel=rel, abs=1e-12), \
                    (key, metric)


# ---------------------------------------------------------------------------
# Values


def test_text_in_a_value_column(case):
    lines = case.csv_lines()
    lines[30] = lines[30].rsplit(",", 1)[0] + ",warm"
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), f"column '{AIR}'", "line 31",
                   "'warm' is not a number")


@pytest.mark.parametrize("token", ["inf", "-inf", "nan", "NaN", "Infinity"])
def test_non_finite_text_is_an_error_and_keeps_the_previous_validation(case, token):
    lines = case.csv_lines()
    header = lines[0].split(",")
    fields = lines[40].split(",")
    fields[header.index(HEATING)] = token
    lines[40] = ",".join(fields)
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), f"column '{HEATING}'", "line 41",
                   "not a finite number")


def test_thousands_separators_are_read_and_stated(case):
    frame = case.hourly.copy()
    frame[HEATING] = frame[HEATING] * 0 + 1234.5     # every hour 1,234.5 W
    plain = case.write(frame, "plain.csv")
    assert_ok(case.validate(plain))
    expected = _metrics(case)
    quoted = case.text(plain.read_text().replace(",1234.5,", ',"1,234.5",'), "quoted.csv")
    assert '"1,234.5"' in quoted.read_text()
    text = assert_ok(case.validate(quoted))
    assert "thousands separators" in " ".join(text.split())
    _assert_same_metrics(expected, _metrics(case))


def test_ambiguous_or_decimal_comma_is_an_error(case):
    lines = case.csv_lines()
    header = lines[0].split(",")
    fields = lines[10].split(",")
    fields[header.index(HEATING)] = '"1,234"'
    lines[10] = ",".join(fields)
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), f"column '{HEATING}'", "line 11",
                   "ambiguous")
    fields[header.index(HEATING)] = '"27,5"'
    lines[10] = ",".join(fields)
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n", "comma.csv"), "line 11",
                   "decimal comma")


# ---------------------------------------------------------------------------
# Whole files


def test_empty_file(case):
    _assert_fails_cleanly(case, case.text(""), "empty")


def test_header_only_file(case):
    _assert_fails_cleanly(case, case.text(case.csv_lines()[0] + "\n"), "no data rows")


def test_random_bytes(case):
    data = np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    _assert_fails_cleanly(case, case.text(data, "random.csv"), "line")


def test_gzip_file(case):
    packed = gzip.compress("\n".join(case.csv_lines()).encode())
    _assert_fails_cleanly(case, case.text(packed, "measured.csv.gz"), "gzip")


def test_missing_and_misspelled_output_columns(case):
    _assert_fails_cleanly(case, case.write(case.hourly.drop(columns=[AIR])), f"no column '{AIR}'")
    renamed = case.hourly.rename(columns={HEATING: "heating_power_W"})
    _assert_fails_cleanly(case, case.write(renamed, "typo.csv"), f"no column '{HEATING}'",
                   "'heating_power_W' looks like 'heating_power_w'")


def test_a_misspelled_output_column_is_an_error_where_no_column_is_required(case):
    """``run --measured`` needs no particular output, yet a typo of one is no extra column."""
    renamed = case.hourly.rename(columns={HEATING: "heating_power_W"})
    _assert_fails_cleanly(case, case.write(renamed, "typo.csv"), "'heating_power_W'",
                          f"did you mean '{HEATING}'", command="run", extra=("--no-progress",))


def test_a_row_index_written_with_the_data_is_left_out_with_a_note(case):
    """pandas' to_csv with its index: a first column with no name is no measurement."""
    indexed = case.hourly.reset_index()
    text = assert_ok(case.validate(case.text(indexed.to_csv(), "indexed.csv")))
    assert "column(s) 1 of line 1 have no name" in " ".join(text.split())


def test_no_timestamp_column(case):
    renamed = case.hourly.reset_index().rename(columns={"timestamp": "time"})
    _assert_fails_cleanly(case, case.text(renamed.to_csv(index=False), "nostamp.csv"),
                   "no 'timestamp' column", "time")


# ---------------------------------------------------------------------------
# Timestamps


def test_bad_timestamp_names_the_line(case):
    lines = case.csv_lines()
    lines[5] = "yesterday," + lines[5].split(",", 1)[1]
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), "line 6", "'yesterday'")


def test_duplicate_stamp_names_both_lines(case):
    lines = case.csv_lines()
    lines.insert(11, lines[10])
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), "line 12", "repeats line 11")


def test_unsorted_stamps_are_sorted_and_stated(case):
    assert_ok(case.validate(case.write(case.hourly, "sorted.csv")))
    expected = _metrics(case)
    shuffled = case.hourly.sample(frac=1.0, random_state=1)
    text = assert_ok(case.validate(case.write(shuffled, "shuffled.csv")))
    assert "not in order" in " ".join(text.split()) and "rows sorted" in text
    _assert_same_metrics(expected, _metrics(case))


def test_utc_offsets_are_converted_to_the_models_standard_time(case):
    """San Francisco's weather file says UTC-8: UTC and DST-offset stamps give the same metrics."""
    assert_ok(case.validate(case.write(case.hourly, "local.csv")))
    expected = _metrics(case)
    utc = case.hourly.copy()
    utc.index = (utc.index + pd.Timedelta(hours=8)).strftime("%Y-%m-%dT%H:%M:%SZ")
    text = assert_ok(case.validate(case.write(utc, "utc.csv")))
    assert "converted to the model's local standard time (UTC-08:00" in " ".join(text.split())
    _assert_same_metrics(expected, _metrics(case))
    # half the rows as daylight saving time (-07:00: one hour later on the clock)
    mixed = case.hourly.copy()
    clock = mixed.index + pd.to_timedelta(np.arange(len(mixed)) % 2, unit="h")
    mixed.index = [f"{t:%Y-%m-%dT%H:%M:%S}{'-07:00' if i % 2 else '-08:00'}"
                   for i, t in enumerate(clock)]
    text = assert_ok(case.validate(case.write(mixed, "dst.csv")))
    assert "each stamp converted by its own" in " ".join(text.split())
    _assert_same_metrics(expected, _metrics(case))


@pytest.mark.parametrize("spelling", ["-08", "-0800", " -08:00", "+01", "z", " UTC", " GMT",
                                      "compact"])
def test_every_iso_zone_designator_is_applied(case, spelling):
    """Hours-only offsets, lower-case z and UTC/GMT were read as UTC wall-clock time (no note)."""
    assert_ok(case.validate(case.write(case.hourly, "local.csv")))
    expected = _metrics(case)
    shifted = case.hourly.copy()
    hours = {"-08": 0, "-0800": 0, " -08:00": 0, "+01": 9}.get(spelling, 8)
    clock = shifted.index + pd.Timedelta(hours=hours)
    if spelling == "compact":
        shifted.index = clock.strftime("%Y%m%dT%H%M%SZ")
    else:
        shifted.index = [f"{t:%Y-%m-%dT%H:%M:%S}{spelling}" for t in clock]
    text = assert_ok(case.validate(case.write(shifted, "zoned.csv")))
    assert "converted to the model's local standard time (UTC-08:00" in " ".join(text.split())
    _assert_same_metrics(expected, _metrics(case))


def test_a_time_zone_name_is_refused_with_the_way_out(case):
    lines = case.csv_lines()
    lines[1:] = [line.replace(",", " PST,", 1) for line in lines[1:]]
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), "line 2",
                          "time-zone names are not read", "UTC offset")


def test_a_number_beyond_the_float_range_is_refused(case):
    lines = case.csv_lines()
    header = lines[0].split(",")
    column = header.index(HEATING)
    cells = lines[6].split(",")
    cells[column] = "1e309"
    lines[6] = ",".join(cells)
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), "line 7", HEATING,
                          "'1e309' is beyond the range")


def test_mixing_stamps_with_and_without_offset_is_an_error(case):
    lines = case.csv_lines()
    stamp, rest = lines[7].split(",", 1)
    lines[7] = stamp.replace(" ", "T") + "+01:00," + rest
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), "line 8", "UTC offset")


def test_a_weather_without_time_zone_and_no_model_record_is_refused(case, tmp_path):
    config = load_config(case.config)
    lines = Path(config.model.weather).read_text().splitlines(keepends=True)
    fields = lines[0].rstrip("\r\n").split(",")
    fields[8] = ""
    lines[0] = ",".join(fields) + "\n"
    epw = tmp_path / "no_zone.epw"
    epw.write_text("".join(lines))
    raw = yaml.safe_load(case.config.read_text())
    raw["model"]["weather"] = str(epw)
    (tmp_path / "cfg").mkdir()
    other = write_config(tmp_path / "cfg", raw)
    # no record of the simulated weather: validate cannot tell which model the results are
    # of, and says so before it reads the stamps
    (case.run_dir / "simulation.json").unlink()
    utc = case.hourly.copy()
    utc.index = (utc.index + pd.Timedelta(hours=8)).strftime("%Y-%m-%dT%H:%M:%SZ")
    before = snapshot(case.run_dir)
    result = invoke("validate", other, "--measured", case.write(utc, "utc.csv"), "--run-dir",
                    case.run_dir)
    assert_clean_error(result, "simulation.json is missing")
    assert_unchanged(before, case.run_dir)


def test_rows_outside_the_test_windows(case):
    early = case.hourly.copy()
    early.index = early.index - pd.Timedelta(days=30)
    partly = pd.concat([early.iloc[:10], case.hourly])
    text = assert_ok(case.validate(case.write(partly, "partly.csv")))
    assert "10 of 106 rows lie outside every test window and were left out" in " ".join(
        text.split())
    other_year = case.hourly.copy()
    other_year.index = other_year.index - pd.DateOffset(years=4)
    _assert_fails_cleanly(case, case.write(other_year, "2021.csv"), "no row falls in any test window",
                   "2021-12-05 01:00:00", "2021-12-09 00:00:00", "H-ST: 2025-12-05 00:00:00")


# ---------------------------------------------------------------------------
# Resolution


def _quarter_hours(hourly: pd.DataFrame, spread: float, seed: int = 0) -> pd.DataFrame:
    """15-min rows whose hour means are exactly ``hourly``; within-hour swings of ± ``spread``."""
    rng = np.random.default_rng(seed)
    stamps = (hourly.index.values[:, None]
              - pd.to_timedelta([45, 30, 15, 0], unit="min").values[None, :]).ravel()
    frame = pd.DataFrame(index=pd.DatetimeIndex(stamps, name="timestamp"))
    for column in hourly.columns:
        swing = rng.normal(0, 1, (len(hourly), 4))
        swing -= swing.mean(axis=1, keepdims=True)             # hour means unchanged
        scale = spread * np.maximum(np.abs(hourly[column].to_numpy()), 1.0)[:, None]
        frame[column] = (hourly[column].to_numpy()[:, None] + swing * scale).ravel()
    return frame


def test_15_min_data_of_an_hourly_truth_give_the_hourly_metrics(case):
    assert_ok(case.validate(case.write(case.hourly, "hourly.csv")))
    hourly = _metrics(case)
    quarter = _quarter_hours(case.hourly, spread=0.2)
    text = assert_ok(case.validate(case.write(quarter, "quarter.csv")))
    flat = " ".join(text.split())
    assert "quarter.csv: 15-min data aggregated to hourly (mean for W, C; hour-ending bins)" in flat
    aggregated = _metrics(case)
    _assert_same_metrics(hourly, aggregated, rel=1e-6)
    record = case.validation()["measured"]
    assert record["file"].endswith("quarter.csv")
    assert record["aggregation"][HEATING] == "15-min data averaged to hourly"
    assert any("15-min data aggregated to hourly" in n for n in record["notes"])
    assert all("15-min data averaged to hourly" in t["notes"] for t in case.validation()["tests"])
    csv = pd.read_csv(case.run_dir / "validation.csv")
    assert csv["notes"].str.contains("15-min data averaged to hourly").all()
    # the old reading (the :00 rows only) gives different metrics: the test can fail
    on_the_hour = quarter[quarter.index.minute == 0]
    assert_ok(case.validate(case.write(on_the_hour, "on_the_hour.csv")))
    picked = _metrics(case)
    key = ("H-ST", HEATING)
    assert abs(picked[key]["cv_rmse"] - hourly[key]["cv_rmse"]) > 0.01


def test_incomplete_hours_are_left_out_and_stated(case):
    quarter = _quarter_hours(case.hourly, spread=0.1)
    in_warmup = pd.Timestamp("2025-12-05 05:15")        # H-ST's warm-up day: not evaluated
    text = assert_ok(case.validate(case.write(quarter.drop(in_warmup), "gap.csv")))
    assert "left out, not averaged from fewer values" in " ".join(text.split())
    assert "2025-12-05 06:00:00" in text
    evaluated = pd.Timestamp("2025-12-06 10:30")
    text = _assert_fails_cleanly(case, case.write(quarter.drop(evaluated), "gap2.csv"),
                          "lacks 1 of the 24 evaluated hours", "2025-12-06 11:00:00")
    assert "not averaged from fewer values" in " ".join(text.split())


@pytest.mark.parametrize("minutes,needle", [(7, "does not divide"), (120, "coarser")])
def test_steps_that_cannot_be_aggregated(case, minutes, needle):
    stamps = pd.date_range("2025-12-05 02:00", "2025-12-09 00:00",
                           freq=f"{minutes}min", name="timestamp")
    frame = pd.DataFrame({c: 1.0 for c in case.hourly.columns}, index=stamps)
    _assert_fails_cleanly(case, case.write(frame, f"step{minutes}.csv"), needle, f"{minutes}-min"
                   if minutes < 60 else "2-hour")


def test_irregular_steps(case):
    quarter = _quarter_hours(case.hourly, spread=0.1)
    quarter = quarter.rename(index={pd.Timestamp("2025-12-05 10:15"):
                                    pd.Timestamp("2025-12-05 10:22")})
    _assert_fails_cleanly(case, case.write(quarter, "irregular.csv"), "irregular time steps",
                   "15-min")


def test_energy_is_summed_power_and_temperature_averaged(tmp_path):
    """Known answer: 250 Wh per quarter hour is 1000 Wh per hour; 1000 W stays 1000 W."""
    raw = short_raw()
    raw["outputs"]["heating_energy_wh"] = {"meter": "Heating:EnergyTransfer", "unit": "Wh"}
    raw["outputs"]["air_fast_c"] = {"variable": "Zone Mean Air Temperature", "key": "Cell",
                                    "unit": "C", "frequency": "timestep"}
    raw["model"]["timesteps_per_hour"] = 4
    config = load_config(write_config(tmp_path, raw))
    stamps = pd.date_range("2025-12-05 00:05", "2025-12-06 00:00", freq="5min", name="timestamp")
    minute = stamps.minute.to_numpy()
    frame = pd.DataFrame({"heating_energy_wh": 250.0 / 3, HEATING: 1000.0 + (minute % 10 - 2.5),
                          AIR: 20.0, "air_fast_c": 20.0 + (minute % 15) / 5}, index=stamps)
    path = tmp_path / "energy.csv"
    frame.to_csv(path)
    data = read_measured(path, config)
    hourly = data.frame["heating_energy_wh"].dropna()
    assert len(hourly) == 24 and np.allclose(hourly, 1000.0)
    assert hourly.index[0] == pd.Timestamp("2025-12-05 01:00")
    assert np.allclose(data.frame[HEATING].dropna(), 1000.0)
    fast = data.frame["air_fast_c"].dropna()                 # kept at the 15-min time step
    assert fast.index[1] - fast.index[0] == pd.Timedelta(minutes=15)
    assert np.allclose(fast, 20.0 + (5 + 10 + 0) / 3 / 5)      # minutes 5, 10, 15 -> 1, 2, 0
    assert data.aggregation["heating_energy_wh"] == "5-min data summed to hourly"
    note = " ".join(data.notes)
    assert "sum for Wh" in note and "mean for W" in note and "to 15-min" in note


# ---------------------------------------------------------------------------
# Plausibility


def test_temperature_x1000_is_an_error_unless_allowed(case):
    scaled = case.hourly.copy()
    scaled[AIR] = scaled[AIR] * 1000
    path = case.write(scaled, "x1000.csv")
    _assert_fails_cleanly(case, path, f"column '{AIR}' [C], line 2", "[-60, 100]", "×1000",
                   "--allow-implausible")
    text = assert_ok(case.validate(path, "--allow-implausible"))
    assert "accepted: --allow-implausible" in " ".join(text.split())


def test_power_x1000_against_the_ensemble(case):
    scaled = case.hourly.copy()
    scaled[HEATING] = scaled[HEATING] * 1000
    _assert_fails_cleanly(case, case.write(scaled, "kw_as_w.csv"), f"column '{HEATING}' [W]",
                   "20 × the largest simulated magnitude", "×1000")


def test_power_in_kilowatts_in_a_watt_column_is_far_too_small(case):
    """Every value 1000 × too small passes a ceiling; against the ensemble it is a scale error."""
    scaled = case.hourly.copy()
    scaled[HEATING] = scaled[HEATING] / 1000
    _assert_fails_cleanly(case, case.write(scaled, "w_as_kw.csv"), f"column '{HEATING}' [W]",
                          "times smaller than the simulations'", "kilo-units (kW, kWh)",
                          "[low, high]", "--allow-implausible")


def test_kelvin_in_a_celsius_column(case):
    kelvin = case.hourly.copy()
    kelvin[AIR] = kelvin[AIR] + 273.15
    _assert_fails_cleanly(case, case.write(kelvin, "kelvin.csv"), "kelvin in a °C column?")


def test_config_range_makes_heating_non_negative(case, tmp_path):
    raw = yaml.safe_load(case.config.read_text())
    raw["outputs"][HEATING]["plausible"] = [0, None]
    (tmp_path / "cfg").mkdir()
    config = write_config(tmp_path / "cfg", raw)
    negative = case.hourly.copy()
    negative.iloc[20, negative.columns.get_loc(HEATING)] = -50.0
    before = snapshot(case.run_dir)
    result = invoke("validate", config, "--measured", case.write(negative, "negative.csv"),
                    "--run-dir", case.run_dir)
    assert_clean_error(result, "negative.csv", f"column '{HEATING}'", "line 22",
                       f"outputs.{HEATING}.plausible")
    assert_unchanged(before, case.run_dir)


# ---------------------------------------------------------------------------
# The other commands that take --measured


def test_diagnose_refuses_bad_data_before_writing(case):
    lines = case.csv_lines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ",inf"
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n"), f"column '{AIR}'", "line 4",
                   command="diagnose", extra=("--no-progress",))
    scaled = case.hourly.copy()
    scaled[AIR] = scaled[AIR] * 1000
    _assert_fails_cleanly(case, case.write(scaled, "x1000.csv"), "×1000", command="diagnose",
                   extra=("--no-progress",))


def test_calibrate_refuses_bad_data_before_writing(case):
    duplicated = pd.concat([case.hourly, case.hourly.iloc[[5]]])
    _assert_fails_cleanly(case, case.write(duplicated, "dupes.csv"), "repeats line",
                   command="calibrate", extra=("--no-progress",))
    scaled = case.hourly.copy()
    scaled[AIR] = scaled[AIR] * 1000
    _assert_fails_cleanly(case, case.write(scaled, "x1000.csv"), f"column '{AIR}'", "×1000",
                   command="calibrate", extra=("--no-progress",))


def test_calibrate_bounds_power_by_its_design_when_the_run_has_no_results(case, tmp_path):
    """No results.parquet: the calibration design's ensemble sets the ceiling."""
    raw = yaml.safe_load(case.config.read_text())
    for parameter in raw["parameters"]:
        if parameter["name"] != "glazing_dirt_correction":
            distribution = parameter["distribution"]
            value = {"uniform": lambda d: (d["lower"] + d["upper"]) / 2,
                     "normal": lambda d: d["mean"], "sampler": lambda d: 0}[distribution["type"]]
            parameter["distribution"] = {"type": "constant", "value": float(value(distribution))}
    raw["calibration"] = {"outputs": [HEATING], "resolution": "hourly", "holdout_days": 1,
                          "design": {"runs": 10, "seed": 1}}
    # two evaluated heating days, so that the hold-out leaves one to calibrate on
    raw["model"]["tests"][0]["days"] = 3
    raw["model"]["tests"][1].update(start="12-08", days=1, warmup_days=0)
    (tmp_path / "cfg").mkdir()
    config = write_config(tmp_path / "cfg", raw)
    run_dir = tmp_path / "cfg" / "run"
    scaled = case.hourly.copy()
    scaled[HEATING] = scaled[HEATING] * 1000
    path = case.write(scaled, "kw_as_w.csv")
    result = invoke("calibrate", config, "--measured", path, "--method", "deterministic",
                    "--no-progress")
    assert_clean_error(result, "kw_as_w.csv", f"column '{HEATING}'", "×1000",
                       "20 × the largest simulated magnitude")
    assert not (run_dir / "results.parquet").exists()
    assert not (run_dir / "calibration" / "calibration.json").exists()


def test_run_and_sensitivity_refuse_bad_data(case):
    text = _assert_fails_cleanly(case, case.text(b"\x00\x01binary", "blob.csv"), "binary",
                          command="run", extra=("--no-progress",))
    assert "ran" not in text
    _assert_fails_cleanly(case, case.text("timestamp,heating_power_w\n", "header.csv"),
                   "no data rows", command="sensitivity", extra=("--no-progress",))
    assert not (case.run_dir / "morris").exists()


def test_notes_are_printed_by_every_command(case):
    quarter = _quarter_hours(case.hourly, spread=0.1)
    path = case.write(quarter, "quarter.csv")
    result = invoke("run", case.config, "--measured", path, "--run-dir", case.run_dir,
                    "--no-progress")
    assert "15-min data aggregated to hourly" in " ".join(assert_ok(result).split())
    assert "Traceback" not in all_text(result)


def test_slash_dates_are_read_with_one_format_or_refused_as_ambiguous(case):
    hourly = case.hourly.copy()
    original = hourly.index
    hourly.index = original.strftime("%d/%m/%Y %H:%M")
    # Every day of the window is 12 or less: day/month and month/day both read every row.
    _assert_fails_cleanly(case, case.write(hourly, "ambiguous.csv"), "ISO 8601", "line 2")
    # One stamp past the 12th (outside the test windows) settles it as day/month.
    extra = hourly.iloc[[0]].copy()
    extra.index = pd.Index(["13/12/2025 01:00"])
    result = case.validate(case.write(pd.concat([hourly, extra]), "daymonth.csv"))
    text = assert_ok(result)
    assert "read as day/month" in " ".join(text.split())
    day_month = _metrics(case)
    assert_ok(case.validate(case.write(case.hourly, "iso.csv")))
    _assert_same_metrics(_metrics(case), day_month)


def test_hour_beginning_stamps_are_named_with_the_shift_to_make(case):
    shifted = case.hourly.copy()
    shifted.index = shifted.index - pd.Timedelta(hours=1)
    _assert_fails_cleanly(case, case.write(shifted, "hour_beginning.csv"),
                          "look hour-beginning", "add one hour")


def test_fahrenheit_and_joules_per_hour_are_named(case):
    """The hint names the likely unit mistake: °F in a °C column, an hour's J in a W column."""
    fahrenheit = case.hourly.copy()
    fahrenheit[AIR] = fahrenheit[AIR] * 1.8 + 32.0
    _assert_fails_cleanly(case, case.write(fahrenheit, "fahrenheit.csv"), "°F in a °C column?")
    joules = case.hourly.copy()
    joules[HEATING] = joules[HEATING] * 3600.0
    _assert_fails_cleanly(case, case.write(joules, "joules.csv"), f"column '{HEATING}' [W]",
                          "J per hour (an energy) in a W column")


def test_a_semicolon_file_with_decimal_commas_is_named_as_such(case):
    lines = [line.replace(",", ";") for line in case.csv_lines()]
    lines = [lines[0]] + [line.replace(".", ",") for line in lines[1:]]
    _assert_fails_cleanly(case, case.text("\n".join(lines) + "\n", "semicolons.csv"),
                          "separated by ';'", "decimal commas")


def _diagnose(config: Path, measured: Path, run_dir: Path, *extra: object):
    return invoke("diagnose", config, "--measured", measured, "--run-dir", run_dir,
                  "--no-progress", *extra)


def test_diagnose_refuses_data_that_do_not_cover_its_tests(case):
    """Hour-beginning stamps and a file that stops early are named, never silently shifted."""
    beginning = case.hourly.copy()
    beginning.index = beginning.index - pd.Timedelta(hours=1)
    _assert_fails_cleanly(case, case.write(beginning, "hour_beginning.csv"), "hour-beginning",
                          "add one hour", command="diagnose", extra=("--no-progress",))
    _assert_fails_cleanly(case, case.write(beginning, "hour_beginning.csv"), "hour-beginning")
    _assert_fails_cleanly(case, case.write(case.hourly.iloc[:-60], "short.csv"),
                          "the measured data cover", command="diagnose",
                          extra=("--no-progress",))


def test_diagnose_refuses_a_measured_output_that_never_changes(case):
    zero = case.hourly.copy()
    zero[HEATING] = 0.0
    _assert_fails_cleanly(case, case.write(zero, "no_heating.csv"), f"column '{HEATING}'",
                          "every value of the evaluated hours is 0", "diagnosis.output",
                          command="diagnose", extra=("--no-progress",))


def test_reversed_sign_of_a_never_negative_output_is_refused(case):
    """Cooling logged as negative heating: the simulations never go below zero."""
    reversed_sign = case.hourly.copy()
    reversed_sign[HEATING] = -reversed_sign[HEATING]
    _assert_fails_cleanly(case, case.write(reversed_sign, "negative.csv"), f"column '{HEATING}'",
                          "the simulations are never negative", "a reversed sign")
    _assert_fails_cleanly(case, case.write(reversed_sign, "negative.csv"),
                          "the simulations are never negative", command="diagnose",
                          extra=("--no-progress",))


def test_diagnose_without_an_ensemble_judges_scale_by_a_nominal_run(case, tmp_path):
    """No results in the run directory: a kW file in a W column is still refused."""
    fresh = tmp_path / "fresh"
    kilowatts = case.hourly.copy()
    kilowatts[HEATING] = kilowatts[HEATING] / 1000
    result = _diagnose(case.config, case.write(kilowatts, "kw.csv"), fresh)
    assert_clean_error(result, "kw.csv", f"column '{HEATING}'", "times smaller than the "
                       "simulations'", "kilo-units")
    assert not (fresh / "diagnosis" / "diagnosis.json").exists()
    hundredfold = case.hourly.copy()
    hundredfold[HEATING] = hundredfold[HEATING] * 1000
    assert_clean_error(_diagnose(case.config, case.write(hundredfold, "w1000.csv"), fresh),
                       "w1000.csv", f"column '{HEATING}'", "plausible range")


@pytest.mark.parametrize("section, needles", [
    ({"output": "cooling_power_w"}, ("diagnosis.output", "'cooling_power_w' is not an output "
                                                         "of the config's tests")),
    ({"parameters": []}, ("diagnosis.parameters: the list is empty",)),
    ({"parameters": ["ground_reflectance"], "suspects": ["ground_reflectance"]},
     ("diagnosis.suspects[0]", "also fitted")),
])
def test_diagnose_settings_are_checked_before_the_data(case, tmp_path, section, needles):
    """A contradiction in the config is named first, even beside a broken measured file."""
    raw = yaml.safe_load(case.config.read_text())
    raw["diagnosis"] = section
    (tmp_path / "cfg").mkdir()
    config = write_config(tmp_path / "cfg", raw)
    lines = case.csv_lines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ",inf"
    result = _diagnose(config, case.text("\n".join(lines) + "\n", "broken.csv"), case.run_dir)
    assert_clean_error(result, "case.yaml", *needles)


def test_diagnose_refuses_an_out_folder_it_cannot_write(case, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    result = _diagnose(case.config, case.write(case.hourly), case.run_dir, "--out",
                       blocker / "diagnosis")
    assert_clean_error(result, "--out", "a_file is a file")


@pytest.mark.parametrize("separator, needle", [("\t", "separated by tabs"),
                                               ("|", "separated by '|'")])
def test_other_separators_are_named(case, separator, needle):
    text = "\n".join(line.replace(",", separator) for line in case.csv_lines()) + "\n"
    _assert_fails_cleanly(case, case.text(text, "other.csv"), "line 1", needle,
                          "expected commas")


def test_comment_lines_above_the_header_are_skipped_and_said(case):
    text = "# logger 42, exported 2025-12-10\n# site: test cell\n" + \
        "\n".join(case.csv_lines()) + "\n"
    before = snapshot(case.run_dir)
    path = case.text(text, "commented.csv")
    text_out = assert_ok(case.validate(path))
    assert "2 comment line(s) starting with '#' skipped (line 1 .. 2)" in " ".join(text_out.split())
    plain = case.validate(case.write(case.hourly, "plain.csv"))
    assert plain.exit_code == 0
    assert before.keys() == snapshot(case.run_dir).keys()


def test_an_invalid_ensemble_of_other_tests_is_named_as_such(case, tmp_path):
    other = tmp_path / "other_run"
    other.mkdir()
    results = pd.read_parquet(case.run_dir / "results.parquet")
    results.assign(test="elsewhere").to_parquet(other / "results.parquet")
    before = snapshot(case.run_dir)
    result = case.validate(case.write(case.hourly), "--invalid", other)
    assert_clean_error(result, "--invalid", "other_run", "has no results of H-ST:heating_power_w")
    assert_unchanged(before, case.run_dir)


def test_diagnose_takes_gaps_inside_a_test_but_not_data_short_of_its_ends(case):
    from bpsflow.diagnosis.command import check_span
    from bpsflow.errors import BpsflowError

    config = load_config(case.config)
    gappy = case.hourly.copy()
    gappy.iloc[30:40, gappy.columns.get_loc(HEATING)] = np.nan
    check_span(config, gappy, HEATING, Path("gappy.csv"))          # gaps between: fine
    short = case.hourly.copy()
    short.iloc[-60:, short.columns.get_loc(HEATING)] = np.nan
    with pytest.raises(BpsflowError, match="the measured data cover"):
        check_span(config, short, HEATING, Path("short.csv"))
