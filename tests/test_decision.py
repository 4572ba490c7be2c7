"""Decision risk (seed §4.4.2, eq. 23): the risk function, the permuted-error predictive,
outcomes, rules read from YAML and the intervention's bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bpsflow.config import load_config
from bpsflow.decision.intervention import Hours, Outcome, Setpoint, load_intervention
from bpsflow.decision.outcomes import counted_hours, outcome_values
from bpsflow.decision.risk import (
    accuracy_risk_correlation,
    decision_risk,
    event_happens,
    permuted_error_outcomes,
    underperformance_probability,
)
from bpsflow.errors import BpsflowError

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_eq23_on_constructed_probabilities():
    p = np.array([0.0, 0.1, 0.5, 0.51, 0.9, 1.0])
    np.testing.assert_allclose(decision_risk(p), [0.0, 0.1, 0.5, 0.49, 0.1, 0.0])
    assert decision_risk(0.3, threshold=0.2) == pytest.approx(0.7)
    with pytest.raises(ValueError):
        decision_risk(1.2)


def test_permuted_errors_against_a_hand_computation():
    prediction = np.array([1.0, 2.0, 3.0])
    errors = np.array([0.5, -1.0, 2.0])
    rng = np.random.default_rng(0)
    maxima = permuted_error_outcomes(prediction, errors, lambda s: s.max(axis=1), 6000, rng)
    # the six orders of the errors give these maxima: prediction + each permutation
    hand = {}
    import itertools
    for order in itertools.permutations(range(3)):
        value = float((prediction + errors[list(order)]).max())
        hand[value] = hand.get(value, 0) + 1 / 6
    seen = pd.Series(maxima).round(9).value_counts(normalize=True)
    for value, share in hand.items():
        assert seen[round(value, 9)] == pytest.approx(share, abs=0.02)
    # a total is unchanged by a permutation: the draw's total error shifts it
    totals = permuted_error_outcomes(prediction, errors, lambda s: s.sum(axis=1), 50, rng)
    np.testing.assert_allclose(totals, prediction.sum() + errors.sum())


def test_underperformance_and_events():
    projected = np.array([9.0, 11.0, 10.0, 12.0])
    reference = np.full(4, 10.0)
    heat = event_happens(projected, reference, factor=1.0)
    np.testing.assert_array_equal(heat, [False, True, False, True])
    comfort = event_happens(np.array([0.0, 0.0, 1.0, 0.0]), np.zeros(4), offset=0.5)
    assert underperformance_probability([heat, comfort], "any") == 0.75
    assert underperformance_probability([heat, comfort], "all") == 0.0


def test_outcomes_total_and_discomfort():
    hours = pd.date_range("2017-03-20 01:00", periods=48, freq="h")   # Monday and Tuesday
    mask = counted_hours(hours, Hours(days="weekdays", start_hour=6, end_hour=19))
    assert mask.sum() == 26
    temperature = np.full(48, 20.0)
    discomfort = Outcome(name="d", output="t", statistic="discomfort",
                         setpoint=Setpoint(value_c=21.0), hours=Hours())
    assert outcome_values(discomfort, temperature, np.ones(48, bool), 21.0)[0] == pytest.approx(1.0)
    assert outcome_values(discomfort, temperature, np.ones(48, bool), np.array([19.0]))[0] == 0.0
    total = Outcome(name="e", output="h", statistic="total")
    assert outcome_values(total, np.arange(48.0), mask)[0] == pytest.approx(np.arange(48.0)[mask].sum())


def test_correlation_across_scenarios():
    table = accuracy_risk_correlation({"cv": [0.1, 0.2, 0.3, 0.4]},
                                      {"D1": [0.0, 0.1, 0.2, 0.3], "flat": [0.1] * 4})
    assert table["cv"]["D1"] == pytest.approx(1.0)
    assert table["cv"]["flat"] is None


def test_correlation_caveats_against_the_t_critical_value():
    """n = 3: r_crit = 0.997 (Student t, 1 dof: 12.706 / sqrt(1 + 12.706²)); a risk that moves by
    2 outcomes in 1000 is flagged, one that moves by 0.3 is not."""
    from bpsflow.decision.risk import correlation_caveats

    caveats = correlation_caveats({"D1": [0.002, 0.0, 0.0], "D2": [0.1, 0.4, 0.2]}, 1000)
    assert "3 scenarios: |r| under 1.00 is not significant at 5%" in caveats[0]
    assert len(caveats) == 2 and caveats[1].startswith("D1 differs across the scenarios by 0.002")
    six = correlation_caveats({"D2": [0.1, 0.4, 0.2, 0.3, 0.5, 0.6]}, 1000)
    assert six == ["6 scenarios: |r| under 0.81 is not significant at 5%"]


@pytest.fixture(scope="module")
def hydronic():
    return load_config(CONFIGS / "hydronic.yaml")


def test_shipped_intervention_reads(hydronic):
    intervention = load_intervention(CONFIGS / "hydronic_intervention.yaml", hydronic)
    assert [r.name for r in intervention.rules] == ["D1", "D2"]
    assert intervention.rules[1].events[0].above.factor == 0.9


def _bad(tmp_path: Path, text: str, hydronic) -> str:
    path = tmp_path / "bad.yaml"
    base = (CONFIGS / "hydronic_intervention.yaml").read_text()
    path.write_text(text(base) if callable(text) else text)
    with pytest.raises(BpsflowError) as info:
        from bpsflow.decision.workflow import intervention_config

        intervention = load_intervention(path, hydronic)
        intervention_config(hydronic, intervention, path)
    return str(info.value)


def test_rule_on_unknown_outcome(tmp_path, hydronic):
    message = _bad(tmp_path, lambda t: t.replace("{outcome: week_heating_kwh, above: {factor: 0.9}}",
                                                 "{outcome: week_gas_kwh, above: {factor: 0.9}}"),
                   hydronic)
    assert "rules[1]" in message and "week_gas_kwh" in message and "bad.yaml" in message


def test_unknown_output_and_key(tmp_path, hydronic):
    assert "heat_kwh" in _bad(tmp_path, lambda t: t.replace("output: heating_kwh", "output: heat_kwh"),
                              hydronic)
    assert "unknown key" in _bad(tmp_path, lambda t: t + "\ncolour: blue\n", hydronic)


def test_overlay_with_unknown_config_key(tmp_path, hydronic):
    message = _bad(tmp_path, lambda t: t.replace("change:\n", "change:\n  overlay: {model: {idff: x.idf}}\n"),
                   hydronic)
    assert "change.overlay" in message and "idff" in message and "unknown key" in message
    # a misspelt top-level key too (it was a KeyError)
    message = _bad(tmp_path, lambda t: t.replace("change:\n", "change:\n  overlay: {modle: {idf: x.idf}}\n"),
                   hydronic)
    assert "change.overlay.modle: unknown key" in message and "model" in message


@pytest.mark.parametrize("overlay, key", [("{model: {timesteps_per_hour: 4}}",
                                            "change.overlay.model.timesteps_per_hour"),
                                           ("{design: {samples: 5}}", "change.overlay.design"),
                                           ("{execution: {jobs: 1}}", "change.overlay.execution")])
def test_an_overlay_of_how_the_model_is_simulated_is_refused(tmp_path, hydronic, overlay, key):
    """A time step halved once read as a 2 % heating saving ('implement')."""
    message = _bad(tmp_path, lambda t: t.replace("change:\n", f"change:\n  overlay: {overlay}\n"),
                   hydronic)
    assert key in message and "changes the building" in message


def test_an_intervention_that_changes_nothing_is_refused(tmp_path, hydronic):
    """multiply 1.0 once got an underperformance probability of 0.38 from rounding alone."""
    same = _bad(tmp_path, lambda t: t.replace("add: -5\n    minimum: 25", "add: 0", 1)
                .replace("add: -5\n    minimum: 25", "multiply: 1.0", 1), hydronic)
    assert "changes nothing" in same and "bad.yaml" in same
    overlay = _bad(tmp_path, lambda t: t.split("change:\n")[0] + "change:\n  overlay:\n"
                   "    parameters:\n    - " + _parameter_text(hydronic, "leakage_area") + "\n"
                   "week:" + t.split("week:", 1)[1], hydronic)
    assert "change.overlay" in overlay and "changes nothing" in overlay


def _parameter_text(config, name: str) -> str:
    import json

    return json.dumps(config.parameter(name).model_dump(mode="json", exclude_none=True))


def test_a_fixed_discomfort_setpoint_must_be_a_room_temperature(hydronic):
    from bpsflow.decision.workflow import _setpoints

    samples = pd.DataFrame({"setpoint_meeting_room": [0.5]})
    for value in (-300.0, 50.0):
        outcome = Outcome(name="d", output="meeting_room_air_temperature_c",
                          statistic="discomfort", setpoint=Setpoint(value_c=value))
        with pytest.raises(BpsflowError, match=r"setpoint.value_c: .* not a room temperature"):
            _setpoints(outcome, hydronic, samples)


def test_an_overlay_value_energyplus_refuses_names_the_intervention(tmp_path, hydronic):
    """It named the config and was found after the run plan was printed."""
    raw = hydronic.parameter("leakage_area").model_dump(mode="json", exclude_none=True)
    raw["mode"], raw["distribution"] = "absolute", {"type": "constant", "value": -5.0}
    import json

    message = _bad(tmp_path, lambda t: t.split("change:\n")[0] + "change:\n  overlay:\n"
                   "    parameters:\n    - " + json.dumps(raw) + "\nweek:"
                   + t.split("week:", 1)[1], hydronic)
    assert "bad.yaml" in message and "change.overlay: with the change" in message \
        and "EnergyPlus refuses" in message


def test_edit_of_unknown_field(tmp_path, hydronic):
    message = _bad(tmp_path, lambda t: t.replace("Setpoint at Outdoor Low Temperature",
                                                 "Setpoint at Outdoor Lo Temperature"), hydronic)
    assert "change.edits[0]" in message


def test_edits_are_clipped_at_their_minimum(hydronic):
    from bpsflow.decision.workflow import intervention_config

    path = CONFIGS / "hydronic_intervention.yaml"
    changed, added = intervention_config(hydronic, load_intervention(path, hydronic), path)
    assert sorted(added.values()) == [25.0, 60.0]     # 30 - 5 = 25 (the floor) and 65 - 5
    assert len(changed.parameters) == len(hydronic.parameters) + 2


def test_calibration_from_another_config_is_refused(tmp_path, hydronic):
    import json

    from bpsflow.config import config_fingerprint
    from bpsflow.decision.workflow import read_calibration

    folder = tmp_path / "calibration"
    folder.mkdir()
    pd.DataFrame({"leakage_area": [1.0, 1.2]}).to_parquet(folder / "posterior.parquet")
    record = {"scenario": {"name": "main"}, "parameters": [{"name": "leakage_area"}],
              "config": {"source": "other.yaml", "fingerprint": "0123456789abcdef"}}
    (folder / "calibration.json").write_text(json.dumps(record))
    with pytest.raises(BpsflowError, match="another config"):
        read_calibration(folder, hydronic)
    record["config"]["fingerprint"] = config_fingerprint(hydronic)
    record["parameters"] = [{"name": "south_wall_insulation_conductivity"}]
    (folder / "calibration.json").write_text(json.dumps(record))
    with pytest.raises(BpsflowError, match="does not have"):
        read_calibration(folder, hydronic)
    record["parameters"] = [{"name": "leakage_area"}]
    (folder / "calibration.json").write_text(json.dumps(record))
    assert read_calibration(folder, hydronic).parameters == ["leakage_area"]
    (folder / "posterior.parquet").unlink()
    with pytest.raises(BpsflowError, match="posterior"):
        read_calibration(folder, hydronic)


def test_decide_command_reports_bad_input_without_traceback(tmp_path):
    from typer.testing import CliRunner

    from bpsflow.cli import app

    bad = tmp_path / "bad.yaml"
    bad.write_text((CONFIGS / "hydronic_intervention.yaml").read_text().replace(
        "{outcome: discomfort_degree_hours, above: {factor: 1.0, offset: 0.5}}",
        "{outcome: comfort, above: {factor: 1.0, offset: 0.5}}"))
    result = CliRunner().invoke(app, ["decide", str(CONFIGS / "hydronic.yaml"), "--calibration",
                                      str(tmp_path / "none"), "--intervention", str(bad),
                                      "--run-dir", str(tmp_path / "run")])
    assert result.exit_code == 2
    assert "unknown outcome 'comfort'" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "run" / "decision").exists()


def test_outcome_hours_that_count_nothing_are_refused_before_any_run(tmp_path, hydronic):
    """An empty or reversed hour range, or weekend hours in a week without a weekend day,
    is refused when the file is read (it once failed after the simulations)."""
    reversed_hours = _bad(tmp_path, lambda t: t.replace("end_hour: 19", "end_hour: 5"), hydronic)
    assert "hours" in reversed_hours and "start_hour" in reversed_hours
    weekends = _bad(tmp_path, lambda t: t.replace("days: weekdays", "days: weekends")
                    .replace("days: 7", "days: 5"), hydronic)
    assert "count no hour of the week" in weekends


def test_an_edit_clashing_with_a_parameter_names_that_parameter_and_object(tmp_path, hydronic):
    """The clash test compares model fields, not object types: an edit of one object is
    refused only when a parameter sets that very object's field, and the refusal names it."""
    from bpsflow.decision.workflow import intervention_config

    path = CONFIGS / "hydronic_intervention.yaml"
    intervention = load_intervention(path, hydronic)
    edit = intervention.change.edits[0]
    clashing = hydronic.model_copy(deep=True)
    clashing.parameters[0] = clashing.parameters[0].model_copy(
        update={"targets": [edit.target]})
    with pytest.raises(BpsflowError) as info:
        intervention_config(clashing, intervention, path)
    assert clashing.parameters[0].name in str(info.value)
    assert f"'{edit.target.name}'" in str(info.value) or "*" in edit.target.name
    intervention_config(hydronic, intervention, path)     # the shipped pair does not clash


def test_an_edit_outside_the_idd_range_names_the_edit(tmp_path, hydronic):
    message = _bad(tmp_path, lambda t: t.replace(
        "{object: 'SetpointManager:OutdoorAirReset', name: '*', field: Setpoint at Outdoor Low "
        "Temperature}\n    add: -5\n    minimum: 25",
        "{object: Material, name: 'Brick Outer Leaf', field: Thickness}\n    set: -1", 1),
        hydronic)
    assert "change.edits[0]" in message and "EnergyPlus refuses" in message


def test_decision_runs_cover_the_week_and_its_warm_up_only(hydronic):
    """The re-runs simulate the test week after its test's warm-up days, not the whole
    calibration period: same evaluated days, a fraction of the simulated ones."""
    from datetime import date

    from bpsflow.config import period_dates, test_dates, window_config

    first, last = date(2017, 3, 20), date(2017, 3, 26)
    week = window_config(hydronic, first, last)
    test = week.model.tests[0]
    start, evaluated, end = test_dates(test, week.model.year)
    assert (evaluated, end) == (first, last)
    assert test.warmup_days == hydronic.model.tests[0].warmup_days
    assert period_dates(week.model.periods[0], week.model.year) == (start, last)
    assert len(week.model.tests) == 1 and week.parameters == hydronic.parameters


def test_unreadable_intervention_yaml_is_named_not_an_internal_error(tmp_path, hydronic):
    assert "not valid YAML" in _bad(tmp_path, "name: x\nchange: [unclosed\n", hydronic)
    repeated = _bad(tmp_path, lambda t: t + "\nname: again\n", hydronic)
    assert "bad.yaml" in repeated and "name" in repeated


def test_overlay_may_only_give_known_parameters_a_value(tmp_path, hydronic):
    """A new parameter name would stack a second change on a field; a distribution would
    leave the intervention's value undecided (each draw kept its calibrated one)."""
    def overlay(parameter: str, distribution: str):
        return lambda t: t.replace("change:\n", (
            "change:\n  overlay:\n    parameters:\n"
            f"    - {{name: {parameter}, group: infiltration, mode: relative, "
            f"distribution: {distribution}, targets: [{{object: "
            "'ZoneInfiltration:EffectiveLeakageArea', name: '*', "
            "field: Effective Air Leakage Area}]}\n"))
    unknown = _bad(tmp_path, overlay("tighter_envelope", "{type: constant, value: 0.5}"),
                   hydronic)
    assert "unknown parameter 'tighter_envelope'" in unknown and "change.edits" in unknown
    spread = _bad(tmp_path, overlay("leakage_area", "{type: uniform, lower: 0.4, upper: 0.6}"),
                  hydronic)
    assert "'leakage_area'" in spread and "constant" in spread


def test_an_overlaid_calibrated_parameter_takes_the_interventions_value(tmp_path, hydronic):
    """The draws carry every calibrated input; the one the intervention sets must not keep
    its posterior value in the changed runs (it once did, silently)."""
    from bpsflow.decision.workflow import intervention_config, overlaid_parameters

    path = tmp_path / "sealed.yaml"
    path.write_text((CONFIGS / "hydronic_intervention.yaml").read_text().replace(
        "change:\n", "change:\n  overlay:\n    parameters:\n"
        "    - {name: leakage_area, group: infiltration, mode: relative, distribution: "
        "{type: constant, value: 0.5}, targets: [{object: 'ZoneInfiltration:EffectiveLeakageArea', "
        "name: '*', field: Effective Air Leakage Area}]}\n"))
    changed, _ = intervention_config(hydronic, load_intervention(path, hydronic), path)
    assert [p.name for p in overlaid_parameters(hydronic, changed)] == ["leakage_area"]
    assert changed.parameter("leakage_area").distribution.nominal == 0.5


def test_discomfort_needs_a_temperature_and_an_edit_a_consistent_range(tmp_path, hydronic):
    on_energy = _bad(tmp_path, lambda t: t.replace("output: meeting_room_air_temperature_c",
                                                   "output: heating_kwh"), hydronic)
    assert "discomfort" in on_energy and "°C" in on_energy and "heating_kwh" in on_energy
    summed = _bad(tmp_path, lambda t: t.replace("output: heating_kwh, statistic: total",
                                                "output: meeting_room_air_temperature_c, "
                                                "statistic: total"), hydronic)
    assert "statistic" in summed and "meeting_room_air_temperature_c" in summed
    crossed = _bad(tmp_path, lambda t: t.replace("add: -5\n    minimum: 25",
                                                 "add: -5\n    minimum: 25\n    maximum: 20",
                                                 1), hydronic)
    assert "change.edits[0]" in crossed and "above maximum" in crossed


def test_a_setpoint_parameter_must_give_a_room_setpoint(hydronic):
    from bpsflow.decision.workflow import _setpoints

    samples = pd.DataFrame({"setpoint_meeting_room": [0.5], "glazing_u_value": [1.0]})
    fine = Outcome(name="d", output="meeting_room_air_temperature_c", statistic="discomfort",
                   setpoint=Setpoint(parameter="setpoint_meeting_room"))
    assert _setpoints(fine, hydronic, samples)[0] == pytest.approx(21.5)
    wrong = fine.model_copy(update={"setpoint": Setpoint(parameter="glazing_u_value")})
    with pytest.raises(BpsflowError, match="not a schedule a ThermostatSetpoint object uses"):
        _setpoints(wrong, hydronic, samples)


def test_a_setpoint_parameter_must_set_a_thermostat_schedule(hydronic):
    """A lighting density of 6-14 W/m² passed the 5-35 °C range and made every hour
    comfortable (the decision flipped)."""
    from bpsflow.decision.workflow import _setpoints

    lighting = "lighting_power_open_office"
    nominal = hydronic.parameter(lighting).distribution.nominal
    samples = pd.DataFrame({lighting: [nominal]})
    outcome = Outcome(name="d", output="meeting_room_air_temperature_c", statistic="discomfort",
                      setpoint=Setpoint(parameter=lighting))
    with pytest.raises(BpsflowError, match=f"'{lighting}' sets .* not a schedule a "
                                           "ThermostatSetpoint object uses"):
        _setpoints(outcome, hydronic, samples)


def test_a_calibration_record_without_parameters_or_with_bad_draws_is_refused(tmp_path,
                                                                            hydronic):
    import json

    from bpsflow.config import config_fingerprint
    from bpsflow.decision.workflow import read_calibration

    folder = tmp_path / "calibration"
    with pytest.raises(BpsflowError, match="calibration does not exist"):
        read_calibration(folder, hydronic)
    folder.mkdir()
    with pytest.raises(BpsflowError, match="no calibration.json in"):
        read_calibration(folder, hydronic)
    good = {"parameters": [{"name": "leakage_area"}],
            "config": {"fingerprint": config_fingerprint(hydronic)}}
    pd.DataFrame({"leakage_area": [1.0, 1.2]}).to_parquet(folder / "posterior.parquet")
    for record in ([1, 2], {"parameters": []}, {"parameters": "glazing"}, {}):
        (folder / "calibration.json").write_text(json.dumps(record))
        with pytest.raises(BpsflowError, match="'parameters' lists"):
            read_calibration(folder, hydronic)
    (folder / "calibration.json").write_text(json.dumps(good))
    for column in ([], [1.0, float("nan")], [1.0, -3.0]):
        pd.DataFrame({"leakage_area": column}, dtype=float).to_parquet(folder / "posterior.parquet")
        with pytest.raises(BpsflowError, match="posterior.parquet"):
            read_calibration(folder, hydronic)


def test_a_decision_of_another_intervention_with_the_same_name_is_kept(tmp_path, hydronic):
    import json

    from bpsflow.decision.workflow import _check_earlier_decision, intervention_fingerprint

    intervention = load_intervention(CONFIGS / "hydronic_intervention.yaml", hydronic)
    fingerprint = intervention_fingerprint(intervention)
    (tmp_path / "decision.json").write_text(json.dumps({"intervention_fingerprint": fingerprint}))
    _check_earlier_decision(tmp_path, fingerprint, Path("x.yaml"))        # the same file again
    other = intervention.model_copy(update={"week": intervention.week.model_copy(
        update={"days": 6})})
    with pytest.raises(BpsflowError, match="same name whose content differs"):
        _check_earlier_decision(tmp_path, intervention_fingerprint(other), Path("x.yaml"))


def test_decide_waits_for_no_calibrate_writing_its_calibration_folder(tmp_path):
    """decide with another --run-dir once read and wrote a calibration folder while a
    calibrate (of another run directory) was writing it."""
    import subprocess
    import sys
    import time

    from typer.testing import CliRunner

    from bpsflow.cli import app

    calibration = tmp_path / "calibration"
    calibration.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom bpsflow.simulation.rundir import RunLock\n"
         "with RunLock(sys.argv[1]):\n    print('held', flush=True)\n    time.sleep(60)\n",
         str(calibration)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        started = time.monotonic()
        result = CliRunner().invoke(app, ["decide", str(CONFIGS / "hydronic.yaml"),
                                          "--calibration", str(calibration), "--intervention",
                                          str(CONFIGS / "hydronic_intervention.yaml"),
                                          "--run-dir", str(tmp_path / "scratch")])
        assert time.monotonic() - started < 30
    finally:
        holder.kill()
    assert result.exit_code == 2, result.output
    assert "is in use by another bpsflow process" in " ".join(result.output.split())


def test_two_edits_of_one_field_name_the_earlier_edit(tmp_path, hydronic):
    message = _bad(tmp_path, lambda t: t.replace(
        "field: Setpoint at Outdoor High Temperature}", "field: Setpoint at Outdoor Low Temperature}"),
        hydronic)
    assert "change.edits[1]: change.edits[0] already edits" in message
    assert "intervention_edit" not in message
