"""diagnose never crashes on one bad run: clipped perturbations, failed runs left out, notes.

Known answers: the shipped glazing (sample_idf/README.md) has visible
transmittance 0.898 and visible reflectance 0.081 (both faces), solar
transmittance 0.837 and solar reflectance 0.075, so EnergyPlus's
``T + R < 1`` allows multipliers up to (1 − 0.081)/0.898 = 1.02339 and
(1 − 0.075)/0.837 = 1.10514 of the transmittances, and (1 − 0.898)/0.081 =
1.25926 of the visible reflectances.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bpsflow.config import load_config
from bpsflow.diagnosis.fitting import Problem, fit_many
from bpsflow.diagnosis.signatures import (
    Candidate,
    candidate_parameters,
    clip_to_physical,
    physical_range,
    signatures,
)

sys.path.insert(0, str(Path(__file__).parent))
from test_simulation import design, toy_config  # noqa: E402
from toy_backend import ToyBackend  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DIAGNOSIS = ROOT / "configs" / "diagnosis.yaml"


@pytest.fixture(scope="module")
def shipped():
    config = load_config(DIAGNOSIS)
    return config, {p.name: float(p.distribution.nominal) for p in config.parameters}


def test_glazing_perturbation_is_clipped_to_t_plus_r_below_one(shipped):
    config, sample = shipped
    lower, upper, notes = physical_range(config, sample, "glazing_visible_transmittance",
                                         0.5, 1.5)
    assert lower == 0.5                                   # the low end is accepted as it is
    assert upper == pytest.approx((1 - 0.081) / 0.898, abs=1e-5)
    assert 0.898 * upper + 0.081 < 1.0                     # strictly inside: EnergyPlus runs
    assert len(notes) == 1 and "1.5 clipped to 1.02339" in notes[0]
    assert "Visible Transmittance" in notes[0] and "sum must be < 1" in notes[0]
    _, solar, _ = physical_range(config, sample, "glazing_solar_transmittance", 0.5, 1.5)
    assert solar == pytest.approx((1 - 0.075) / 0.837, abs=1e-5)
    _, reflectance, _ = physical_range(config, sample, "glazing_front_visible_reflectance",
                                       0.5, 1.5)
    assert reflectance == pytest.approx((1 - 0.898) / 0.081, abs=1e-5)
    # a field with no IDF bound in reach is left alone, without a note
    assert physical_range(config, sample, "south_wall_gypsum_density", 0.5, 1.5) == \
        (0.5, 1.5, [])


def test_clipped_candidates_perturb_within_the_limits_and_divide_by_the_change(shipped):
    """+10 % of the visible transmittance (fatal before) becomes −10 %; a range with no
    room for 10 % either way moves by what is left, and the signature is per unit change."""
    config, sample = shipped
    notes: list[str] = []
    candidates = clip_to_physical(
        config, sample, [c for c in candidate_parameters(config.parameters, [], 0.5)
                         if c.parameter.name == "glazing_visible_transmittance"], notes)
    assert len(candidates) == 1 and candidates[0].upper == pytest.approx(1.02339, abs=1e-5)
    assert any("glazing_visible_transmittance: 1.5 clipped" in n for n in notes)
    narrow = Candidate(candidates[0].parameter, 1.0, 0.99, candidates[0].upper, half_width=0.5)
    response = np.linspace(1.0, 2.0, 24)
    asked: list[float] = []

    def simulate(samples: pd.DataFrame) -> np.ndarray:
        values = samples["glazing_visible_transmittance"].to_numpy()
        asked.extend(values)
        return 100.0 + values[:, None] * response

    prediction = 100.0 + 1.0 * response
    found = signatures(simulate, sample, [candidates[0], narrow], prediction, notes=notes)
    assert asked == pytest.approx([0.9, candidates[0].upper])   # down 10 %; up to the limit
    for signature in found:
        np.testing.assert_allclose(signature.response, response, rtol=1e-6)


def test_a_failed_signature_run_is_retried_at_half_the_change_then_left_out(shipped):
    config, sample = shipped
    parameter = next(p for p in config.parameters if p.name == "glazing_solar_transmittance")
    other = next(p for p in config.parameters if p.name == "south_wall_gypsum_density")
    retried = Candidate(parameter, 1.0, 0.5, 1.5)      # its +0.1 fails, +0.05 runs
    hopeless = Candidate(other, 1.0, 0.5, 1.5)          # fails whatever the change
    calls: list[pd.DataFrame] = []

    class Failing:
        failures: dict[int, str] = {}

        def __call__(self, samples: pd.DataFrame) -> np.ndarray:
            calls.append(samples)
            out = np.tile(samples["glazing_solar_transmittance"].to_numpy()[:, None], 24)
            self.failures = {}
            for row, (_, values) in enumerate(samples.iterrows()):
                if values["glazing_solar_transmittance"] > 1.06 or \
                        values["south_wall_gypsum_density"] != 1.0:
                    out[row] = np.nan
                    self.failures[row] = "**  Fatal  ** engine says no"
            return out

    notes: list[str] = []
    found = signatures(Failing(), sample, [retried, hopeless], np.ones(24), notes=notes)
    assert [len(c) for c in calls] == [2, 2]            # one batch, one retry batch
    assert calls[1]["glazing_solar_transmittance"].iloc[0] == pytest.approx(1.05)
    assert [s.candidate.parameter.name for s in found] == ["glazing_solar_transmittance"]
    np.testing.assert_allclose(found[0].response, 1.0)  # (1.05 − 1) / 0.05
    assert len(notes) == 1
    assert "south_wall_gypsum_density left out" in notes[0] and "failed twice" in notes[0]
    assert "engine says no" in notes[0]


def test_fit_many_rejects_a_failed_trial_and_fails_only_the_problem_that_cannot_start(shipped):
    """A linear simulator whose first trial batch fails, and a problem whose start fails."""
    config, _ = shipped
    parameters = [p for p in config.parameters
                  if p.name in ("glazing_dirt_correction", "wall_stack_coefficient")]
    hours = 200
    rng = np.random.default_rng(1)
    basis = rng.normal(size=(hours, 2)) * [50.0, 20.0]

    class Simulator:
        def __init__(self):
            self.calls = 0
            self.failures: dict[int, str] = {}

        def __call__(self, samples: pd.DataFrame) -> np.ndarray:
            self.calls += 1
            theta = samples[["glazing_dirt_correction", "wall_stack_coefficient"]].to_numpy()
            out = 500.0 + theta @ basis.T
            broken = (samples["marker"].to_numpy() == 1.0) | (self.calls == 2)
            out[broken] = np.nan
            self.failures = {int(row): f"crash in call {self.calls}"
                             for row in np.flatnonzero(broken)}
            return out

    calibration = np.arange(hours) < 150
    measured = 500.0 + basis @ [0.8, 1.1] + rng.normal(0, 1.0, hours)
    base = {p.name: 1.0 for p in config.parameters}
    good = Problem({**base, "marker": 0.0}, parameters, measured, calibration)
    doomed = Problem({**base, "marker": 1.0}, parameters, measured, calibration)
    fits = fit_many(Simulator(), [good, doomed])
    y = measured[calibration] - 500.0
    design_rows = np.vstack([basis[calibration], basis[calibration].mean(axis=0)
                             * np.sqrt(len(y))])
    expected = np.linalg.lstsq(design_rows, np.concatenate([y, [y.mean() * np.sqrt(len(y))]]),
                               rcond=None)[0]
    assert not fits[0].failed
    assert fits[0].values == pytest.approx(expected, abs=2e-3)
    assert fits[0].failed_trials == ["crash in call 2"]
    assert fits[1].failed and "crash in call 1" in fits[1].failure
    assert np.isnan(fits[1].prediction).all() and fits[1].objective == float("inf")


@pytest.mark.parametrize("vectorised", [False, True])
def test_simulate_batch_records_failed_instances_and_keeps_the_others(tmp_path, vectorised):
    from bpsflow.simulation.ensemble import BatchFailure, simulate_batch, simulate_samples

    config = toy_config(tmp_path)
    samples = design(4, first=1.0)
    samples.iloc[[1, 3], 0] = -1.0                         # the toy backend's crash
    outcome = simulate_batch(config, samples, tmp_path / "w", ToyBackend(vectorised=vectorised))
    assert sorted(outcome.failed) == [1, 3]
    assert "toy crash" in outcome.failed[1]
    assert sorted(outcome.tidy["instance"].unique()) == [0, 2]
    with pytest.raises(BatchFailure, match="2 of 4 runs failed"):
        simulate_samples(config, samples, tmp_path / "w2", ToyBackend(vectorised=vectorised))


# ---------------------------------------------------------------------------
# A later step that fails keeps what was found; a base fit that fails writes nothing


@pytest.fixture(scope="module")
def gain_case(tmp_path_factory):
    """A 150 W weekday office gain the surrogate model lacks (24 days, 7 held out)."""
    from bpsflow.diagnosis.hidden import make_case

    sys.path.insert(0, str(Path(__file__).parent))
    from test_diagnosis import FITTED_TRUTH, base_config

    folder = tmp_path_factory.mktemp("robust_case")
    base = base_config(folder / "base")
    return base, make_case(base, folder / "truth", "office_gain", 150.0, FITTED_TRUTH,
                           seed=3).measured


@pytest.mark.slow
def test_a_failing_signature_step_still_writes_diagnosis_json(gain_case, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from bpsflow.cli import app
    from bpsflow.diagnosis import workflow

    def broken(*args, **kwargs):
        raise RuntimeError("signature batch exploded")

    monkeypatch.setattr(workflow, "signatures", broken)
    base, measured = gain_case
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["diagnose", str(base), "--measured", str(measured),
                                      "--out", str(out), "--no-progress"])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "diagnosis.json").read_text())
    assert record["verdict"] == "none" and record["rounds"][0]["significant"]
    assert any("stopped at step 'signatures'" in n and "signature batch exploded" in n
               for n in record["notes"])
    assert "before naming a cause" in record["cause"]["summary"]
    assert record["scorecard"]["base"]["heldout"]["cvrmse"] > 0


def test_a_failed_base_fit_exits_with_one_line_and_writes_nothing(gain_case, tmp_path,
                                                                  monkeypatch):
    from typer.testing import CliRunner

    from bpsflow.cli import app
    from bpsflow.diagnosis.fitting import OutputSimulator

    def nothing_runs(self, samples):
        self.failures = {row: "** Fatal ** no run" for row in range(len(samples))}
        return np.full((len(samples), len(self.timestamps)), np.nan)

    monkeypatch.setattr(OutputSimulator, "__call__", nothing_runs)
    base, measured = gain_case
    out = tmp_path / "out"
    out.mkdir()
    (out / "diagnosis.md").write_text("an earlier diagnosis")
    result = CliRunner().invoke(app, ["diagnose", str(base), "--measured", str(measured),
                                      "--out", str(out), "--no-progress"])
    assert result.exit_code != 0
    assert "nothing to diagnose" in result.output and "no run" in result.output
    assert "Traceback" not in result.output
    assert not (out / "diagnosis.json").exists()
    # a diagnosis that fails leaves the earlier report where it was
    assert (out / "diagnosis.md").read_text() == "an earlier diagnosis"


# ---------------------------------------------------------------------------
# EnergyPlus: a signature run that no clipping saves; the diagnosis still writes its record

#: Raising the minimum wind speed of the exterior convection curve above its maximum
#: (40 m/s) is within the IDD but fatal for EnergyPlus ("Minimum Value of x > Maximum").
FATAL_WHEN_RAISED = {
    "name": "exterior_wind_curve_min_speed", "group": "convection", "mode": "absolute",
    "distribution": {"type": "constant", "value": 39.0},
    "targets": [{"object": "Curve:Linear", "name": "ExteriorWindConvectionCurve",
                 "field": "Minimum Value of x"}]}


@pytest.mark.energyplus
@pytest.mark.slow
def test_energyplus_diagnosis_with_a_fatal_signature_run_writes_its_record(tmp_path):
    """A 400 W weekday gain makes structure (so the signatures run, 15 days calibrated); the
    curve parameter's run fails at +10 % and at +5 %, the glazing's is clipped below T + R = 1."""
    from typer.testing import CliRunner

    from bpsflow.cli import app
    from bpsflow.diagnosis.hidden import make_case

    sys.path.insert(0, str(Path(__file__).parent))
    from test_diagnosis import base_config

    base = base_config(tmp_path / "base", days=17, backend="energyplus", extra={
        "parameters": [FATAL_WHEN_RAISED],
        "diagnosis": {"output": "heating_power_w", "holdout_days": 2,
                      "parameters": ["glazing_dirt_correction"], "parameter_candidates": 1,
                      "suspects": ["exterior_wind_curve_min_speed",
                                   "glazing_visible_transmittance"],
                      "extensions": [], "max_rounds": 1, "max_fit_iterations": 4,
                      "start_screen": 4, "fit_starts": 1}})
    case = make_case(base, tmp_path / "truth", "office_gain", 400.0,
                     {"glazing_dirt_correction": 0.92}, seed=3, backend="energyplus")
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["diagnose", str(base), "--measured", str(case.measured),
                                      "--out", str(out), "--no-progress", "--jobs", "2"])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "diagnosis.json").read_text())
    assert record["verdict"] == "model_form"
    notes = record["notes"]
    left_out = [n for n in notes if "exterior_wind_curve_min_speed left out" in n]
    assert len(left_out) == 1 and "failed twice" in left_out[0]
    assert "Minimum Value of x" in left_out[0]               # EnergyPlus's own reason
    assert any("glazing_visible_transmittance: 1.5 clipped to 1.02339" in n for n in notes)
    checked = {p["name"] for p in record["parameter_check"]}
    assert "exterior_wind_curve_min_speed" not in checked
    assert "## Notes" in (out / "diagnosis.md").read_text()


def test_a_jump_of_the_output_when_the_candidates_are_added_at_zero_is_noted():
    """One recovery hour 200 W off (an EnergyPlus HVAC threshold flipped by a token object)
    is named with its hour; a change within the noise, or none, is not."""
    from bpsflow.diagnosis.workflow import nesting_note

    rng = np.random.default_rng(0)
    hours = pd.date_range("2025-03-06 01:00", periods=24 * 20, freq="h")
    current = 500.0 + 100.0 * np.sin(np.arange(len(hours)) / 24.0 * 2 * np.pi)
    measured = current + rng.normal(0.0, 5.0, len(hours))
    calibration = np.arange(len(hours)) < 24 * 15
    assert nesting_note(measured, current.copy(), current, calibration, hours, "space_w",
                        3, 1) is None
    assert nesting_note(measured, current + 0.3, current, calibration, hours, "space_w",
                        3, 1) is None
    jumped = current.copy()
    jumped[150] -= 200.0
    note = nesting_note(measured, jumped, current, calibration, hours, "space_w", 3, 2)
    assert note is not None and note.startswith("round 2:")
    assert str(hours[150]) in note and "space_w" in note and "1 calibration hour(s)" in note
    jumped_held_out = current.copy()
    jumped_held_out[-5] -= 200.0                  # the held-out hours are not fitted
    assert nesting_note(measured, jumped_held_out, current, calibration, hours, "space_w",
                        3, 1) is None
    failed = current.copy()
    failed[:] = np.nan
    assert "did not run" in nesting_note(measured, failed, current, calibration, hours,
                                         "space_w", 3, 1)


def test_a_screen_start_is_fitted_again_only_when_its_own_run_beats_the_first_fit():
    """One batch runs every promised start; only a start whose BIC is truly lower is kept.

    Known BICs: the outputs are the measured series plus a chosen error, so
    each point's BIC is the closed form ``n ln(RSS/n) + k ln n``.
    """
    from types import SimpleNamespace

    from bpsflow.diagnosis import comparison
    from bpsflow.diagnosis.workflow import _Context, _run_checked

    hours = 100
    rng = np.random.default_rng(2)
    measured = 500.0 + rng.normal(0, 5.0, hours)
    calibration = np.arange(hours) < 80
    small_error, large_error = rng.normal(0, 1.0, hours), rng.normal(0, 20.0, hours)
    batches: list[pd.DataFrame] = []

    def simulate(samples: pd.DataFrame) -> np.ndarray:
        batches.append(samples)
        out = np.array([measured + {1.0: small_error, 2.0: large_error}.get(level, 0.0)
                        for level in samples["level"]])
        out[samples["level"].to_numpy() == 3.0] = np.nan        # a run that fails
        return out

    context = SimpleNamespace(data=SimpleNamespace(y=measured, calibration=calibration),
                              simulator=lambda config, label: simulate, timings={})
    context.run_rows = lambda *args, **kwargs: _Context.run_rows(context, *args, **kwargs)
    reached = comparison.bic(rng.normal(0, 5.0, 80), 3)        # the first fits' end
    starts = [{"level": 1.0}, {"level": 2.0}, None, {"level": 3.0}]
    kept = _run_checked(context, None, {"level": 0.0, "other": 7.0}, starts,  # type: ignore
                        [3, 3, 3, 3], [reached] * 4, round_number=1)
    assert kept == [{"level": 1.0}, None, None, None]
    assert len(batches) == 1 and list(batches[0]["level"]) == [1.0, 2.0, 3.0]
    assert (batches[0]["other"] == 7.0).all()
    assert "round1_screen_check" in context.timings


def test_a_fitted_input_at_the_end_of_its_range_is_noted():
    """A window U fitted at its lower bound stood in for a missing gain, without a word."""
    from types import SimpleNamespace

    from bpsflow.config import IdfTarget, Parameter
    from bpsflow.diagnosis.workflow import _fitted_input_bound_notes
    from bpsflow.distributions import Uniform

    def parameter(name, group="inputs"):
        return Parameter(name=name, group=group, mode="absolute",
                         distribution=Uniform(type="uniform", lower=3.0, upper=6.0),
                         targets=[IdfTarget(object="Material", name="M", field="Conductivity")])

    fit = SimpleNamespace(parameters=[parameter("window_u"), parameter("plug"),
                                      parameter("gain", "extension")],
                          values=np.array([3.0, 4.5, 6.0]))
    notes = _fitted_input_bound_notes(fit)
    assert len(notes) == 1 and "window_u = 3" in notes[0] and "lower end" in notes[0]


def test_accepted_extensions_report_the_final_models_sizes():
    """A night gain split over two rounds reported 95 W / radiant 0 (its round's fit) while
    the final model, whose gain the verdict quotes, held 149 W / 0.52."""
    from types import SimpleNamespace

    from bpsflow.diagnosis.workflow import _final_sizes

    first = {"accepted": True, "fitted": {"scheduled_gain_w": 95.0},
             "parameter_names": {"scheduled_gain_w": "scheduled_gain_w_v1"}}
    a, b = "infiltration_a_m3s", "infiltration_b_m3s_per_k"
    law = {"accepted": True, "fitted": {a: 0.01, b: 0.0},
           "parameter_names": {a: f"{a}_v2", b: f"{b}_v2"},
           "law": "flow = 0.01 m³/s", "terms": [a]}
    rejected = {"accepted": False, "fitted": {"x": 1.0}, "parameter_names": {"x": "x"}}
    final = {"scheduled_gain_w_v1": 149.4, f"{a}_v2": 0.02, f"{b}_v2": 0.0, "x": 5.0}
    result = SimpleNamespace(extensions=[first, law, rejected],
                             final=SimpleNamespace(fit=SimpleNamespace(named=final)))
    _final_sizes(result)
    assert first["fitted"] == {"scheduled_gain_w": 149.4}
    assert first["fitted_when_accepted"] == {"scheduled_gain_w": 95.0}
    assert law["law"] == "flow = 0.02 m³/s"
    assert rejected["fitted"] == {"x": 1.0} and "fitted_when_accepted" not in rejected
