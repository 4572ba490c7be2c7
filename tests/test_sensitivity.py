"""Morris screening: known elementary effects, window responses, screened configs, the CLI."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from bpsflow.alignment import evaluation_hours
from bpsflow.cli import app
from bpsflow.config import load_config
from bpsflow.config import test_dates as dates_of_test
from bpsflow.distributions import Constant
from bpsflow.errors import BpsflowError
from bpsflow.sampling import latin_hypercube_unit, morris_unit, sample
from bpsflow.sensitivity import (
    GROUP_COLUMNS,
    INDEX_COLUMNS,
    grid_from_unit,
    kept_parameters,
    morris_config,
    morris_design,
    morris_indices,
    prepare_morris,
    window_responses,
    write_screened_config,
)

from conftest import short_raw, write_config

NAMES = [f"x{i}" for i in range(5)]


def _design(levels: int, trajectories: int = 12, seed: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A real SALib Morris design through the mid-point mapping, and its grid coordinate.

    The grid coordinate is SALib's ``j / (levels - 1)`` for the level ``j`` whose
    mid-point ``(j + 0.5) / levels`` the design holds.
    """
    unit = morris_unit([type("P", (), {"name": n})() for n in NAMES], trajectories, levels, seed)
    grid = (unit * levels - 0.5) / (levels - 1)
    return unit, grid


def _indices(unit, levels, y) -> pd.DataFrame:
    frame = morris_indices(NAMES, unit, pd.DataFrame({"r": y}), levels, seed=0)
    return frame.set_index("parameter")


@pytest.mark.parametrize("levels", [4, 10])
def test_linear_function_has_mu_star_equal_to_its_coefficients(levels):
    unit, grid = _design(levels)
    coefficients = np.array([3.0, -2.0, 0.5, 0.0, 7.0])
    indices = _indices(unit, levels, grid @ coefficients + 11.0)
    np.testing.assert_allclose(indices.loc[NAMES, "mu_star"], np.abs(coefficients), atol=1e-12)
    np.testing.assert_allclose(indices.loc[NAMES, "mu"], coefficients, atol=1e-12)
    np.testing.assert_allclose(indices.loc[NAMES, "sigma"], 0.0, atol=1e-12)
    assert list(indices.sort_values("rank").index[:3]) == ["x4", "x0", "x1"]
    # in the design's own quantile coordinate u the range is (levels - 1) / levels shorter
    in_unit = _indices(unit, levels, unit @ coefficients)
    np.testing.assert_allclose(in_unit.loc[NAMES, "mu_star"],
                               np.abs(coefficients) * (levels - 1) / levels, atol=1e-12)


def test_pure_interaction_and_null_input_match_their_elementary_effects():
    levels, trajectories = 4, 60
    unit, grid = _design(levels, trajectories, seed=8)
    y = (grid[:, 0] - 0.5) * (grid[:, 1] - 0.5)       # x2..x4 do nothing
    indices = _indices(unit, levels, y)
    # the effect of x0 is (x1 - 0.5) at the step where x0 moves, and vice versa
    expected = {0: [], 1: []}
    for trajectory in grid.reshape(trajectories, len(NAMES) + 1, len(NAMES)):
        for step in range(len(NAMES)):
            moved = int(np.argmax(np.abs(trajectory[step + 1] - trajectory[step]) > 1e-9))
            if moved in expected:
                expected[moved].append(trajectory[step, 1 - moved] - 0.5)
    for i in (0, 1):
        effects = np.asarray(expected[i])
        row = indices.loc[NAMES[i]]
        assert row["mu"] == pytest.approx(effects.mean(), abs=1e-12)
        assert row["mu_star"] == pytest.approx(np.abs(effects).mean(), abs=1e-12)
        assert row["sigma"] == pytest.approx(effects.std(ddof=1), abs=1e-12)
        assert row["mu_star"] >= 1 / 6 - 1e-12          # |x - 0.5| >= 1/6 on a 4-level grid
        assert abs(row["mu"]) < 0.5 * row["mu_star"]      # effects of both signs cancel
        assert row["sigma"] > 0.2
    for name in NAMES[2:]:
        assert indices.loc[name, "mu_star"] == 0.0 and indices.loc[name, "sigma"] == 0.0


def test_failed_runs_drop_their_trajectory_and_bad_designs_are_refused():
    levels, trajectories = 4, 6
    unit, grid = _design(levels, trajectories)
    y = grid @ np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    y[len(NAMES) + 3] = np.nan                         # a failed run in trajectory 2
    frame = morris_indices(NAMES, unit, pd.DataFrame({"r": y}), levels)
    assert (frame["trajectories"] == trajectories - 1).all()
    np.testing.assert_allclose(frame.set_index("parameter").loc[NAMES, "mu_star"],
                               [1, 2, 3, 4, 5], atol=1e-12)
    with pytest.raises(BpsflowError, match="not on the mid-points"):
        grid_from_unit(latin_hypercube_unit(12, 5, random_state=0), levels)
    with pytest.raises(BpsflowError, match="not a Morris design"):
        morris_indices(NAMES, np.roll(unit, 1, axis=0), pd.DataFrame({"r": y}), levels)


@pytest.fixture
def case(tmp_path):
    return load_config(write_config(tmp_path, short_raw()))


def _constructed_results(config, warmup_value: float = 1000.0) -> pd.DataFrame:
    """Instance i predicts 10 i + (k mod 5) - 2 at evaluated hour k; warm-up hours are huge."""
    frames = []
    for test in config.model.tests:
        first, _, last = dates_of_test(test, config.model.year)
        every = pd.date_range(pd.Timestamp(first) + pd.Timedelta(hours=1),
                              pd.Timestamp(last) + pd.Timedelta(days=1), freq="h")
        evaluated = every.isin(evaluation_hours(test, config.model.year))
        for output in test.outputs:
            for instance in range(3):
                k = np.cumsum(evaluated) - 1
                value = np.where(evaluated, 10.0 * instance + (k % 5) - 2, warmup_value)
                frames.append(pd.DataFrame({"instance": instance, "test": test.name,
                                            "output": output, "timestamp": every,
                                            "value": value}))
    return pd.concat(frames, ignore_index=True)


def test_window_responses_exclude_warmup_and_difference_is_raw_minus_measured(case):
    results = _constructed_results(case)
    hours = pd.DatetimeIndex(sorted(set().union(*[evaluation_hours(t, case.model.year)
                                                  for t in case.model.tests])))
    # measured 5, 15, 5, ...: instance 1 (8 .. 12) is above and below it
    measured = pd.DataFrame({"heating_power_w": 5.0 + 10.0 * (np.arange(len(hours)) % 2),
                             "zone_air_temperature_c": 5.0 + 10.0 * (np.arange(len(hours)) % 2)},
                            index=hours)
    raw = window_responses(case, results, kind="raw")
    assert list(raw.columns) == ["H-ST:heating_power_w", "H-FF:zone_air_temperature_c"]
    window = [evaluation_hours(t, case.model.year) for t in case.model.tests]
    pattern = (np.arange(len(window[0])) % 5 - 2).mean()    # 24 h of (h mod 5) - 2
    np.testing.assert_allclose(raw["H-ST:heating_power_w"], 10.0 * np.arange(3) + pattern)
    difference = window_responses(case, results, measured, "difference")
    measured_mean = measured.loc[window[0], "heating_power_w"].mean()
    np.testing.assert_allclose(difference, raw - measured_mean)
    absolute = window_responses(case, results, measured, "absolute")
    prediction = (np.arange(24) % 5 - 2)[None, :] + 10.0 * np.arange(3)[:, None]
    observed = measured.loc[window[0], "heating_power_w"].to_numpy()
    np.testing.assert_allclose(absolute["H-ST:heating_power_w"],
                               np.abs(prediction - observed).mean(axis=1))
    assert absolute.iloc[1, 0] > abs(difference.iloc[1, 0]) + 1.0
    with pytest.raises(BpsflowError, match="--measured"):
        window_responses(case, results, None, "difference")
    with pytest.raises(BpsflowError, match="no column 'zone_air_temperature_c'"):
        window_responses(case, results, measured[["heating_power_w"]], "absolute", "m.csv")


def test_screened_config_fixes_the_rest_at_nominal_and_loads(case, tmp_path):
    names = [p.name for p in case.parameters]
    keep_a, keep_b = ["ground_reflectance", "stratification_gradient"], ["return_air_offset"]
    rows = []
    for response, kept in (("H-ST:heating_power_w", keep_a), ("H-FF:zone_air_temperature_c",
                                                               keep_b)):
        order = kept + [n for n in names if n not in kept]
        for rank, name in enumerate(order, start=1):
            rows.append({"response": response, "parameter": name,
                         "group": case.parameter(name).group, "mu": 0.0,
                         "mu_star": 100.0 / rank if rank <= len(names) - 3 else 0.0,
                         "mu_star_conf": 0.0, "sigma": 0.0, "rank": rank})
    indices = pd.DataFrame(rows)
    out = tmp_path / "sub" / "reduced.yaml"
    path, kept, fixed = write_screened_config(case, indices, top=2, out_path=out)
    assert set(kept) == {"ground_reflectance", "stratification_gradient", "return_air_offset",
                         names[0]}                      # names[0] is 2nd for the second response
    reduced = load_config(path)
    assert yaml.safe_load(path.read_text())["extends"] == "../case.yaml"
    assert reduced.run_dir == case.run_dir.parent / "run_screened"
    for original in case.parameters:
        new = reduced.parameter(original.name)
        assert new.mode == original.mode and new.targets == original.targets
        if original.name in kept:
            assert new.distribution == original.distribution and new.provenance is None
        else:
            assert isinstance(new.distribution, Constant)
            assert new.distribution.value == pytest.approx(original.distribution.nominal)
            assert new.provenance["best_rank"] >= 3
    sampler = reduced.parameter("floor_boundary_sampler")
    assert sampler.distribution.value == 10.0            # sequence index floor(0.5 * 20)
    assert reduced.parameter("thermostat_offset").provenance["max_mu_star"] == 0.0
    # the reduced config samples (constants at their value) and steps only the kept inputs
    values = sample(reduced).values
    assert (values["floor_boundary_sampler"] == 10.0).all()
    assert values["stratification_gradient"].nunique() > 1
    design = morris_design(reduced, trajectories=2, levels=4)
    assert sorted(design.unit.columns) == sorted(kept) and len(design.unit) == 2 * (len(kept) + 1)
    assert (design.values["thermostat_offset"] == 0.0).all()


def test_screening_ties_keep_inputs_not_told_apart_from_the_last_kept():
    """--screen N --screen-ties: mu* 0.34 ± 0.10 is the 2nd of response A; 0.28 ± 0.04
    reaches 0.24 and is kept, 0.19 ± 0.04 does not; response B's tie is its own; a null
    input (mu* 0) is never kept."""
    indices = pd.DataFrame({
        "response": ["A"] * 5 + ["B"] * 3,
        "parameter": ["big", "second", "tied", "apart", "null", "b1", "b2", "b3"],
        "mu_star": [2.6, 0.34, 0.28, 0.19, 0.0, 1.0, 0.5, 0.45],
        "mu_star_conf": [0.7, 0.10, 0.04, 0.04, 0.5, 0.1, 0.02, 0.04],
        "rank": [1, 2, 3, 4, 5, 1, 2, 3]})
    assert kept_parameters(indices, 2) == ["big", "b1", "second", "b2"]
    assert kept_parameters(indices, 2, ties=True) == ["big", "b1", "second", "b2", "tied",
                                                      "b3"]
    # a top that reaches past every input keeps them all but the null one
    assert set(kept_parameters(indices, 9, ties=True)) == set(indices["parameter"]) - {"null"}


def test_fixed_boundary_sampler_outside_the_sequences_is_refused(tmp_path):
    raw = short_raw(boundary_sequences=20)
    raw["parameters"] = [dict(p, distribution={"type": "constant", "value": 20})
                         if p["name"] == "floor_boundary_sampler" else p for p in raw["parameters"]]
    with pytest.raises(BpsflowError, match=r"sequence index.*0\.\.19, got 20"):
        load_config(write_config(tmp_path, raw))


def test_morris_design_is_redrawn_when_its_settings_change(case):
    messages = []
    first = prepare_morris(morris_config(case, 2, 4), "surrogate", messages.append)
    again = prepare_morris(morris_config(case, 2, 4), "surrogate", messages.append)
    pd.testing.assert_frame_equal(first, again)
    assert messages == []
    (case.run_dir / "morris" / "instances" / "000001").mkdir(parents=True)
    redrawn = prepare_morris(morris_config(case, 2, 6), "surrogate", messages.append)
    assert len(messages) == 1 and "design.levels 4 → 6" in messages[0]
    assert "its 1 run instance(s) and results were moved to" in messages[0]
    assert not (case.run_dir / "morris" / "instances").exists()
    # the finished runs of the earlier design are kept, not deleted
    kept = list((case.run_dir / "morris" / "previous").glob("*/instances/000001"))
    assert len(kept) == 1 and kept[0].is_dir()
    assert not redrawn.equals(first)
    with pytest.raises(BpsflowError, match="even number of levels"):
        morris_config(case, 2, 5)


@pytest.mark.slow
def test_sensitivity_cli_on_the_surrogate(tmp_path):
    raw = short_raw()
    # a rare second value no Morris level reaches: the input is never stepped, and said so
    rare = next(p for p in raw["parameters"] if p["name"] == "thermostat_offset")
    rare["distribution"] = {"type": "discrete", "values": [0.0, 0.5], "weights": [0.99, 0.01]}
    config = write_config(tmp_path, raw)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "samples.parquet").write_bytes(b"LHS design")   # must be left alone
    result = CliRunner().invoke(app, [
        "sensitivity", str(config), "--backend", "surrogate", "--trajectories", "2",
        "--levels", "4", "--jobs", "1", "--top", "5", "--no-progress", "--screen", "4"])
    assert result.exit_code == 0, result.output
    assert (run_dir / "samples.parquet").read_bytes() == b"LHS design"
    morris = run_dir / "morris"
    indices = pd.read_csv(morris / "sensitivity.csv")
    assert list(indices.columns) == INDEX_COLUMNS
    assert list(pd.read_csv(morris / "sensitivity_groups.csv").columns) == GROUP_COLUMNS
    assert len(pd.read_parquet(morris / "samples.parquet")) == 2 * 61
    by = indices.set_index(["response", "parameter"])
    for response in ("H-ST:heating_power_w", "H-FF:zone_air_temperature_c"):
        assert sorted(by.loc[response, "rank"]) == list(range(1, 61))
        # the surrogate has no physics for these: no effect at all
        assert by.loc[(response, "thermostat_offset"), "mu_star"] == 0.0
        assert by.loc[(response, "wind_direction_error_deg"), "mu_star"] == 0.0
        assert (morris / "figures" / f"morris_{response.replace(':', '_')}.png").is_file()
    # the free-floating zone air temperature depends on the air temperature gradient,
    # monotonically
    gradient = by.loc[("H-FF:zone_air_temperature_c", "stratification_gradient")]
    assert gradient["mu_star"] > 0 and abs(gradient["mu"]) == pytest.approx(gradient["mu_star"])
    assert "H-ST:heating_power_w" in result.output and "rank" in result.output
    assert "never changes thermostat_offset" in " ".join(result.output.split())
    reduced = load_config(tmp_path / "case_screened.yaml")
    assert reduced.run_dir == tmp_path / "run_screened"
    fixed = [p for p in reduced.parameters if isinstance(p.distribution, Constant)]
    assert 60 - 8 <= len(fixed) <= 60 - 4                  # 4 to 8 kept (top 4 of 2 responses)


def test_sensitivity_cli_bad_input_exits_2_before_running(tmp_path):
    config = write_config(tmp_path, short_raw())
    runner = CliRunner()
    result = runner.invoke(app, ["sensitivity", str(config), "--response", "difference"])
    assert result.exit_code == 2 and "--measured" in result.output
    result = runner.invoke(app, ["sensitivity", str(config), "--top", "0"])
    assert result.exit_code == 2 and "--top" in result.output
    result = runner.invoke(app, ["sensitivity", str(config), "--screen-ties"])
    assert result.exit_code == 2 and "--screen-ties needs --screen" in result.output
    measured = tmp_path / "measured.csv"
    case = load_config(config)
    hours = evaluation_hours(case.model.tests[0], case.model.year)
    pd.DataFrame({"timestamp": hours, "heating_power_w": 1.0}).to_csv(measured, index=False)
    result = runner.invoke(app, ["sensitivity", str(config), "--measured", str(measured),
                                 "--backend", "surrogate"])
    assert result.exit_code == 2
    assert "measured.csv" in result.output and "zone_air_temperature_c" in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "run" / "morris" / "results.parquet").exists()


def test_screening_keeping_every_input_writes_a_config_that_loads(case, tmp_path):
    """--screen N at or above the number of inputs fixes nothing: no empty ``parameters``."""
    names = [p.name for p in case.parameters]
    indices = pd.DataFrame([{"response": "H-ST:heating_power_w", "parameter": name,
                             "group": case.parameter(name).group, "mu": 0.0, "mu_star": 1.0,
                             "mu_star_conf": 0.0, "sigma": 0.0, "rank": rank}
                            for rank, name in enumerate(names, start=1)])
    path, kept, fixed = write_screened_config(case, indices, top=len(names) + 5,
                                              out_path=tmp_path / "all.yaml")
    assert fixed == [] and kept == names
    assert "parameters" not in yaml.safe_load(path.read_text())
    assert [p.distribution for p in load_config(path).parameters] == \
        [p.distribution for p in case.parameters]
    # written again over its own earlier result: allowed (it is bpsflow's file)
    write_screened_config(case, indices, top=2, out_path=path)


def test_sensitivity_refuses_outputs_that_would_overwrite_a_users_file(tmp_path):
    base = write_config(tmp_path, short_raw())
    child = tmp_path / "child.yaml"
    child.write_text("extends: case.yaml\n")
    notes = tmp_path / "notes.yaml"
    notes.write_text("my own notes\n")
    runner = CliRunner()
    for target, needle in ((base, "a base config it extends"), (child, "the config given"),
                           (notes, "exists and is not a reduced config")):
        before = target.read_text() if target.is_file() else None
        result = runner.invoke(app, ["sensitivity", str(child), "--screen", "2", "--screen-out",
                                     str(target), "--backend", "surrogate", "--no-progress"])
        flat = " ".join(result.output.split())
        assert result.exit_code == 2, result.output
        assert "--screen-out" in flat and needle in flat, result.output
        assert "Traceback" not in result.output
        if before is not None:
            assert target.read_text() == before
        # refused before any run
        assert not (tmp_path / "run" / "morris" / "samples.parquet").exists()


def test_raw_response_refuses_a_measured_file_it_would_ignore(tmp_path):
    config = write_config(tmp_path, short_raw())
    measured = tmp_path / "measured.csv"
    measured.write_text("timestamp,heating_power_w\n")
    result = CliRunner().invoke(app, ["sensitivity", str(config), "--response", "raw",
                                      "--measured", str(measured)])
    assert result.exit_code == 2 and "--response raw" in " ".join(result.output.split())
    assert not (tmp_path / "run" / "morris").exists()
