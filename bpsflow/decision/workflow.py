"""``bpsflow decide``: the decision risk of an intervention from a calibrated model (seed §4.4.2).

For one calibration (or every scenario's, ``--scenarios``):

1. take ``sampling.posterior_draws`` evenly spaced draws of the posterior
   (``posterior.parquet``); parameters the calibration did not calibrate keep
   the values it held them at (their nominal values);
2. re-run every draw on the physical model as it is (business as usual) and
   with the intervention's change, through the one simulation layer, over the
   test week and its test's warm-up days only (:func:`bpsflow.config.window_config`);
   when the week is the calibration's held-out days, its physical check has
   already run the same draws as they are over the same days, and those runs are used;
3. per draw, the errors on the test week (measured minus business-as-usual
   prediction, per output) are permuted ``sampling.permutations`` times and
   added to the draw's intervention prediction (the same permutation for
   every output of a draw, so their joint timing stays together);
4. per rule, the share of the draws x permutations outcomes in which the rule's
   events happen is the underperformance probability ``p``; the decision is
   to implement when ``p <= threshold``, and its risk is eq. 23.

The business-as-usual outcome is the measured one (a discomfort outcome with
a calibrated setpoint gets one value per draw: the measured temperatures
against that draw's setpoint).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd
from rich.console import Console
from rich.markup import escape

from bpsflow.config import Config, IdfTarget, Parameter, config_fingerprint, window_config
from bpsflow.decision.intervention import Intervention, load_intervention, week_dates
from bpsflow.decision.outcomes import counted_hours, outcome_values
from bpsflow.decision.risk import (
    decision_risk,
    event_happens,
    permutation_orders,
    permuted_error_outcomes,
    underperformance_probability,
)
from bpsflow.errors import BpsflowError
from bpsflow.files import read_parquet

DECISION_DIR = "decision"
DECISION_FILE = "decision.json"
DECISION_FIGURE = "decision_risk.png"
#: Plausible room heating setpoints, °C: a setpoint parameter outside gives no comfort bound.
SETPOINT_RANGE_C = (5.0, 35.0)


@dataclass
class Calibrated:
    """One calibration's posterior and where it lives."""

    folder: Path
    name: str
    record: dict
    draws: pd.DataFrame
    parameters: list[str] = field(default_factory=list)


def read_calibration(folder: Path, config: Config) -> Calibrated:
    """``calibration.json`` and ``posterior.parquet`` of one calibration, checked against ``config``."""
    from bpsflow.calibration.report import CALIBRATION_FILE, POSTERIOR_FILE

    folder = Path(folder)
    record_path, posterior_path = folder / CALIBRATION_FILE, folder / POSTERIOR_FILE
    if not folder.is_dir():
        raise BpsflowError(f"--calibration: {folder} does not exist (expected the folder "
                           "'bpsflow calibrate' wrote, RUN_DIR/calibration)")
    if not record_path.is_file():
        raise BpsflowError(f"--calibration: no {CALIBRATION_FILE} in {folder} (expected the "
                           f"folder 'bpsflow calibrate' wrote, RUN_DIR/calibration)")
    try:
        record = json.loads(record_path.read_text())
    except (OSError, ValueError) as exc:
        raise BpsflowError(f"cannot read {record_path}: {exc}") from None
    if not isinstance(record, dict) or not isinstance(record.get("parameters"), list) or not \
            record["parameters"] or not all(isinstance(p, dict) and isinstance(p.get("name"), str)
                                            for p in record["parameters"]):
        raise BpsflowError(f"{record_path}: expected the record 'bpsflow calibrate' writes, a "
                           "mapping whose 'parameters' lists the calibrated parameters by name")
    if record.get("method") not in (None, "bayes") or not posterior_path.is_file():
        raise BpsflowError(f"--calibration: no {POSTERIOR_FILE} in {folder}: a decision needs "
                           f"a Bayesian calibration's posterior (method bayes)")
    wanted = record.get("config", {}).get("fingerprint")
    if wanted is not None and wanted != config_fingerprint(config):
        raise BpsflowError(
            f"--calibration: {folder} was calibrated with another config "
            f"({record['config'].get('source', 'unknown')}: its model, parameters, outputs or "
            f"tests differ from {config.source}); decide with the config it was calibrated with")
    names = [p["name"] for p in record.get("parameters", []) if "name" in p]
    known = {p.name: p for p in config.parameters}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise BpsflowError(f"--calibration: {folder} calibrated parameter(s) "
                           f"{', '.join(unknown)} that {config.source} does not have: it was "
                           f"calibrated with another config")
    draws = read_parquet(posterior_path)
    missing = [n for n in names if n not in draws.columns]
    if missing:
        raise BpsflowError(f"{posterior_path}: no column for calibrated parameter(s) "
                           f"{', '.join(missing)}")
    if draws.empty:
        raise BpsflowError(f"{posterior_path}: no posterior draws (0 rows)")
    for name in names:
        values = pd.to_numeric(draws[name], errors="coerce").to_numpy(dtype=float)
        low, high = (float(v) for v in known[name].distribution.ppf(np.array([0.0, 1.0])))
        outside = ~np.isfinite(values) | (values < low - 1e-9 * max(1.0, abs(low))) | \
            (values > high + 1e-9 * max(1.0, abs(high)))
        if outside.any():
            raise BpsflowError(f"{posterior_path}: column {name}: {int(outside.sum())} draw(s) "
                               f"are not numbers within the parameter's support "
                               f"[{low:g}, {high:g}] (first: {values[outside][0]!r})")
    return Calibrated(folder=folder, name=record.get("scenario", {}).get("name", folder.name),
                      record=record, draws=draws, parameters=names)


def intervention_config(config: Config, intervention: Intervention, source: Path) -> tuple[Config, dict[str, float]]:
    """The config with the intervention's change: its overlay merged, its edits as constants.

    Returns the changed config and the constant parameters the edits add
    (name -> value written to the field).
    """
    from bpsflow.config import with_overlay
    from bpsflow.distributions import Constant
    from bpsflow.simulation.target_bounds import check_value, targeted_fields

    _check_overlay_keys(intervention.change.overlay, source)
    changed = with_overlay(config, intervention.change.overlay, source,
                           where="change.overlay") if intervention.change.overlay else \
        config.model_copy(deep=True)
    _check_overlaid_parameters(config, changed, source)
    if intervention.change.overlay:
        from bpsflow.simulation.target_bounds import check_distribution_support

        try:
            # before any run: the config passed this check, so a failure is the overlay's
            check_distribution_support(changed)
        except BpsflowError as exc:
            raise BpsflowError(f"change.overlay: with the change, {exc.message}",
                               source=source) from None
    added: dict[str, float] = {}
    edit_of: dict[str, int] = {}      # added parameter -> the edit (its index) that made it
    moved = False                     # whether any edit changes a field's value
    for i, edit in enumerate(intervention.change.edits):
        probe = changed.model_copy(deep=True)
        probe.parameters = [Parameter(name="intervention_probe", mode="absolute",
                                      distribution=Constant(type="constant", value=0.0),
                                      targets=[edit.target])]
        try:
            fields = targeted_fields(probe)
        except BpsflowError as exc:
            raise BpsflowError(f"change.edits[{i}].target: {exc.message}", source=source) from None
        if not fields:
            raise BpsflowError(f"change.edits[{i}].target: no {edit.target.object} named "
                               f"'{edit.target.name}' in the model", source=source)
        edited = {_field_key(found) for found in fields}
        clash = [(p.name, found.obj.where) for found in targeted_fields(changed)
                 if _field_key(found) in edited for p in found.parameters]
        earlier = [edit_of[n] for n, _ in clash if n in edit_of]
        if earlier:
            # the intervention's own earlier edit, named as the user wrote it
            raise BpsflowError(f"change.edits[{i}]: change.edits[{earlier[0]}] already edits "
                               f"{clash[0][1]} {edit.target.field}; give each field one edit",
                               source=source)
        if clash:
            raise BpsflowError(f"change.edits[{i}]: parameter {clash[0][0]} already sets "
                               f"{clash[0][1]} {edit.target.field}; change it "
                               f"through change.overlay instead", source=source)
        for found in fields:
            if found.nominal is None:
                raise BpsflowError(f"change.edits[{i}]: {found.obj.where} has no number in "
                                   f"{edit.target.field}", source=source)
            value = (edit.set if edit.set is not None else
                     found.nominal + edit.add if edit.add is not None else
                     found.nominal * float(edit.multiply))  # type: ignore[arg-type]
            if edit.minimum is not None:
                value = max(value, edit.minimum)
            if edit.maximum is not None:
                value = min(value, edit.maximum)
            moved = moved or value != found.nominal
            if value == found.nominal and len(fields) == 1:
                raise BpsflowError(f"change.edits[{i}]: sets {found.obj.where} "
                                   f"{edit.target.field} to {value:g}, the value it has; the "
                                   "edit changes nothing", source=source)
            problem = check_value(found.limits, value)
            if problem:
                raise BpsflowError(f"change.edits[{i}]: sets {found.obj.where} "
                                   f"{edit.target.field} to {value:g}, which EnergyPlus "
                                   f"refuses: the IDD requires {found.limits.describe()} "
                                   f"({problem})", source=source)
            name = f"intervention_edit_{i}_{len(added)}"
            changed.parameters.append(Parameter(
                name=name, mode="absolute", group="intervention",
                distribution=Constant(type="constant", value=float(value)),
                targets=[IdfTarget(object=edit.target.object, name=found.obj.name,
                                   field=edit.target.field)],
                description=f"{found.obj.where}: {edit.target.field} {found.nominal:g} -> {value:g}"))
            added[name] = float(value)
            edit_of[name] = i
    if not moved and not _overlay_changes(config, changed):
        what = ("change.overlay: it gives every parameter and model file the definition it "
                "has" if not intervention.change.edits else
                "change: every edit sets its fields to the values they have"
                + (" and the overlay gives every parameter and model file the definition it has"
                   if intervention.change.overlay else ""))
        raise BpsflowError(f"{what}; the intervention changes nothing", source=source)
    return changed, added


#: What an intervention's overlay may change: the building, not how it is simulated or judged.
OVERLAY_KEYS = {"parameters": None, "model": {"idf", "idf_objects"}}


def _check_overlay_keys(overlay: dict, source: Path) -> None:
    """Refuse an overlay of simulation or analysis settings (time step, periods, design ...).

    The decision compares the model as it is with the model changed; a changed
    time step or test period would be read as the intervention's effect.
    """
    from bpsflow.config import Model

    for key, value in overlay.items():
        if key not in OVERLAY_KEYS and key in Config.model_fields:
            raise BpsflowError(
                f"change.overlay.{key}: an intervention changes the building (parameters, "
                f"model.idf, model.idf_objects); '{key}' is how the model is simulated or "
                "judged, and its change would be read as the intervention's effect",
                source=source)
        if key not in OVERLAY_KEYS:
            raise BpsflowError(
                f"change.overlay.{key}: unknown key; expected "
                + " or ".join(sorted(OVERLAY_KEYS)) + " (parameters, model.idf, "
                "model.idf_objects)", source=source)
        allowed = OVERLAY_KEYS[key]
        if allowed is not None and isinstance(value, dict):
            for inner in value:
                if inner not in allowed and inner in Model.model_fields:
                    raise BpsflowError(
                        f"change.overlay.{key}.{inner}: an intervention changes the building "
                        f"(parameters, model.idf, model.idf_objects); {key}.{inner} is how the "
                        "model is simulated, and its change would be read as the "
                        "intervention's effect", source=source)


def _overlay_changes(config: Config, changed: Config) -> list[str]:
    """What the overlay changes, described (parameters and model files)."""
    said = []
    for parameter in overlaid_parameters(config, changed):
        before = config.parameter(parameter.name)
        said.append(f"parameter {parameter.name}: {_distribution_text(before)} -> "
                    f"{_distribution_text(parameter)}")
    if changed.model.idf != config.model.idf:
        said.append(f"model.idf: {config.model.idf} -> {changed.model.idf}")
    if changed.model.idf_objects != config.model.idf_objects:
        said.append("model.idf_objects: "
                    + (", ".join(map(str, config.model.idf_objects)) or "none") + " -> "
                    + (", ".join(map(str, changed.model.idf_objects)) or "none"))
    return said


def _distribution_text(parameter: Parameter) -> str:
    distribution = parameter.distribution
    if distribution.type == "constant":
        return f"{distribution.nominal:g}"
    return f"{distribution.type} (median {distribution.nominal:g})"


def overlaid_parameters(config: Config, changed: Config) -> list[Parameter]:
    """The parameters the intervention's overlay redefines (same name, another definition)."""
    before = {p.name: p.model_dump(mode="json") for p in config.parameters}
    return [p for p in changed.parameters
            if p.name in before and p.model_dump(mode="json") != before[p.name]]


def _check_overlaid_parameters(config: Config, changed: Config, source: Path) -> None:
    """Refuse an overlay that adds a parameter, or gives one a distribution instead of a value.

    A new name would stack a second change on fields another parameter already
    sets (``change.edits`` changes a field no parameter sets); a distribution
    would leave the intervention's value undecided, and every draw keeps its
    calibrated value.
    """
    known = [p.name for p in config.parameters]
    for parameter in changed.parameters:
        if parameter.name not in known:
            raise BpsflowError(
                f"change.overlay.parameters: unknown parameter '{parameter.name}' (expected one "
                f"of {known}); to change a model field no parameter sets, use change.edits",
                source=source)
    for parameter in overlaid_parameters(config, changed):
        if parameter.distribution.type != "constant":
            raise BpsflowError(
                f"change.overlay.parameters: '{parameter.name}' gets a "
                f"{parameter.distribution.type} distribution; an intervention sets a value "
                f"(distribution: {{type: constant, value: ...}})", source=source)


def _field_key(found) -> tuple[str, str, int]:
    """One model field, whatever target pattern reached it: object type, name, position."""
    return (found.obj.type.lower(), found.obj.name.lower(), found.position)


def _draw_samples(config: Config, calibrated: Calibrated, count: int) -> pd.DataFrame:
    from bpsflow.calibration.design import nominal_sample

    pick = np.linspace(0, len(calibrated.draws) - 1, min(count, len(calibrated.draws))).astype(int)
    base = nominal_sample(config)
    frame = pd.DataFrame([base] * len(pick), index=pd.RangeIndex(len(pick), name="instance"))
    for name in calibrated.parameters:
        frame[name] = calibrated.draws[name].to_numpy()[pick]
    return frame


def _week_series(results: pd.DataFrame, output: str, hour_ends: pd.DatetimeIndex) -> np.ndarray:
    """(instances, hours) matrix of one output over the week's hour-ending stamps."""
    mine = results[results["output"] == output]
    table = mine.pivot_table(index="instance", columns="timestamp", values="value")
    missing = hour_ends.difference(pd.DatetimeIndex(table.columns))
    if len(missing):
        raise BpsflowError(f"the simulations have no {output} at {missing[0]} (the week must lie "
                           f"in a test's evaluated days)")
    return table.reindex(columns=hour_ends).to_numpy()


def _setpoints(outcome, config: Config, samples: pd.DataFrame,
               source: Path | None = None) -> np.ndarray | None:
    """The comfort setpoint per draw (°C): fixed, or the field value the calibrated parameter gives."""
    from bpsflow.simulation.target_bounds import targeted_fields
    from bpsflow.simulation.targets import apply_mode

    if outcome.setpoint is None:
        return None
    if outcome.setpoint.value_c is not None:
        value = outcome.setpoint.value_c
        if not SETPOINT_RANGE_C[0] <= value <= SETPOINT_RANGE_C[1]:
            raise BpsflowError(f"outcomes ({outcome.name}).setpoint.value_c: {value:g} °C is not "
                               f"a room temperature setpoint (expected {SETPOINT_RANGE_C[0]:g}-"
                               f"{SETPOINT_RANGE_C[1]:g} °C)", source=source)
        return np.full(len(samples), value)
    parameter = config.parameter(outcome.setpoint.parameter)
    fields = [f for f in targeted_fields(config) if any(p is parameter for p in f.parameters)
              and f.nominal is not None]
    if not fields:
        raise BpsflowError(f"outcomes ({outcome.name}).setpoint.parameter: '{parameter.name}' "
                           "sets no numeric model field, so it gives no setpoint temperature",
                           source=source)
    if not _sets_a_thermostat_schedule(config, fields[0].obj):
        # a lighting density of 6-14 W/m² passed the 5-35 range below and made every
        # hour comfortable
        raise BpsflowError(f"outcomes ({outcome.name}).setpoint.parameter: '{parameter.name}' "
                           f"sets {fields[0].where}, which is not a schedule a "
                           "ThermostatSetpoint object uses; name the parameter of the zone's "
                           "heating setpoint schedule, or give setpoint.value_c", source=source)
    nominal = float(fields[0].nominal)  # type: ignore[arg-type]  # kept only when numeric
    values: np.ndarray = np.array(apply_mode(parameter.mode, nominal,
                                             samples[parameter.name].to_numpy()), dtype=np.float64)
    # a room's heating setpoint; anything else is a parameter that is not one
    if not np.all((values >= SETPOINT_RANGE_C[0]) & (values <= SETPOINT_RANGE_C[1])):
        raise BpsflowError(
            f"outcomes ({outcome.name}).setpoint.parameter: '{parameter.name}' gives "
            f"{values.min():.3g}..{values.max():.3g} on {fields[0].where}, not a room "
            f"temperature setpoint ({SETPOINT_RANGE_C[0]:g}-{SETPOINT_RANGE_C[1]:g} °C); name "
            "the parameter of the zone's heating setpoint", source=source)
    return values


def _sets_a_thermostat_schedule(config: Config, obj) -> bool:
    """Whether ``obj`` is a schedule that some ``ThermostatSetpoint:*`` object names."""
    from bpsflow.simulation.idf import model_objects

    if not obj.type.startswith("SCHEDULE"):
        return False
    name = obj.name.strip().upper()
    return any(field.strip().upper() == name
               for other in model_objects(config.model).objects
               if other.type.startswith("THERMOSTATSETPOINT:") for field in other.fields)


def decide_one(config: Config, calibrated: Calibrated, intervention: Intervention,
               changed: Config, measured: pd.DataFrame, out_dir: Path, *, backend: str,
               jobs: int | None, show_progress: bool, console: Console,
               source: Path | None = None, provenance: dict | None = None) -> dict:
    """Decision risk of the intervention for one calibration; writes ``decision.json`` and a figure.

    ``provenance`` (the measured file and its read notes) goes into ``decision.json``;
    an earlier decision in ``out_dir`` moves to ``out_dir/previous/<timestamp>/``.
    """
    from bpsflow.calibration.design import run_samples
    from bpsflow.calibration.workflow import checked_runs
    from bpsflow.decision.report import plot_risks
    from bpsflow.files import write_json

    sampling = intervention.sampling
    if sampling.posterior_draws > len(calibrated.draws):
        raise BpsflowError(f"sampling.posterior_draws: {sampling.posterior_draws} draws asked "
                           f"for, but the posterior of {calibrated.folder} holds "
                           f"{len(calibrated.draws)}; ask for at most that many", source=source)
    samples = _draw_samples(config, calibrated, sampling.posterior_draws)
    changed_samples = samples.copy()
    # the intervention's own values win over the draws (a calibrated input it replaces)
    overlaid = {p.name for p in overlaid_parameters(config, changed)}
    for parameter in changed.parameters:
        if parameter.name not in changed_samples or parameter.name in overlaid:
            changed_samples[parameter.name] = float(parameter.distribution.nominal)
    setpoints = {o.name: _setpoints(o, config, samples, source) for o in intervention.outcomes}
    first, last = week_dates(intervention, config)
    hour_ends = week_hour_ends(first, last)
    outputs = sorted({o.output for o in intervention.outcomes})
    observed = {output: measured[output].reindex(hour_ends).to_numpy() for output in outputs}
    console.print(f"{_tag(calibrated)} {len(samples)} posterior draws, each run as it is and "
                  f"with '{intervention.name}'")
    as_is = checked_runs(calibrated.folder, config, samples)
    if as_is is None:
        as_is = run_samples(config, samples, out_dir / "runs_as_is", backend=backend, jobs=jobs,
                            show_progress=show_progress)
    else:
        console.print(f"{_tag(calibrated)} as it is: the calibration's physical check ran these "
                      "draws over the same days; its runs are used")
    with_change = run_samples(changed, changed_samples, out_dir / "runs_intervention",
                              backend=backend, jobs=jobs, show_progress=show_progress)
    predicted_as_is = {o: _week_series(as_is, o, hour_ends) for o in outputs}
    predicted_change = {o: _week_series(with_change, o, hour_ends) for o in outputs}
    if all(np.allclose(predicted_change[o], predicted_as_is[o], rtol=1e-9,
                       atol=1e-9 * (1.0 + float(np.nanmax(np.abs(predicted_as_is[o])))))
           for o in outputs):
        # a decision would then rest on rounding in the permuted errors' sums
        raise BpsflowError(f"change: the intervention leaves {', '.join(outputs)} as they are "
                           f"in every draw over the test week (runs kept in {out_dir}); it "
                           "changes nothing the outcomes measure", source=source)
    rng = np.random.default_rng(sampling.seed)
    draws, perms = len(samples), sampling.permutations
    projected = {o.name: np.empty((draws, perms)) for o in intervention.outcomes}
    reference = {o.name: np.empty((draws, perms)) for o in intervention.outcomes}
    masks = {o.name: counted_hours(hour_ends, o.hours) for o in intervention.outcomes}
    for j in range(draws):
        # one permutation per sample for every output of the draw: their timing stays joint
        order = permutation_orders(perms, len(hour_ends), rng)
        for outcome in intervention.outcomes:
            per_draw = setpoints[outcome.name]
            setpoint = None if per_draw is None else per_draw[j]
            projected[outcome.name][j] = permuted_error_outcomes(
                predicted_change[outcome.output][j],
                observed[outcome.output] - predicted_as_is[outcome.output][j],
                partial(outcome_values, outcome, mask=masks[outcome.name], setpoint_c=setpoint),
                perms, rng, order=order)
            reference[outcome.name][j] = outcome_values(
                outcome, observed[outcome.output], masks[outcome.name], setpoint)[0]
    rules = []
    for rule in intervention.rules:
        events = []
        for event in rule.events:
            bound = event.above if event.above is not None else event.below
            assert bound is not None  # the schema asks for one of them
            events.append(event_happens(projected[event.outcome].ravel(),
                                        reference[event.outcome].ravel(), bound.factor,
                                        bound.offset, above=event.above is not None))
        probability = underperformance_probability(events, rule.underperforms_when)
        rules.append({
            "name": rule.name, "threshold": rule.threshold,
            "underperforms_when": rule.underperforms_when,
            "events": [{**e.model_dump(exclude_none=True), "probability": float(h.mean())}
                       for e, h in zip(rule.events, events)],
            "underperformance_probability": probability,
            "implement": bool(probability <= rule.threshold),
            "decision_risk": float(decision_risk(probability, rule.threshold))})
    record = {
        "intervention": intervention.name,
        "intervention_fingerprint": intervention_fingerprint(intervention),
        "calibration": str(calibrated.folder),
        "scenario": calibrated.name,
        "week": [f"{first:%Y-%m-%d}", f"{last:%Y-%m-%d}"],
        "posterior_draws": draws, "permutations": perms, "outcomes_sampled": draws * perms,
        "seed": sampling.seed,
        "method": "posterior draws re-run on the physical model; model bias added as a random "
                  "permutation of each draw's test-week errors (seed §4.4.2); decision risk eq. 23",
        "outcomes": {o.name: {
            "output": o.output, "statistic": o.statistic,
            "business_as_usual": _summary(reference[o.name][:, 0]),
            "intervention": _summary(projected[o.name].ravel())} for o in intervention.outcomes},
        "rules": rules,
        **(provenance or {}),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    from bpsflow.simulation.rundir import move_aside

    earlier = move_aside(out_dir, (DECISION_FILE, DECISION_FIGURE))
    if earlier is not None:
        console.print(f"{_tag(calibrated)} the earlier decision in {out_dir} was moved to "
                      f"{earlier}", highlight=False)
    write_json(out_dir / DECISION_FILE, record)
    record["figure"] = str(plot_risks(record, out_dir / DECISION_FIGURE))
    return record


def intervention_fingerprint(intervention: Intervention) -> str:
    """A digest of everything the intervention file says (its schema-checked content)."""
    import hashlib

    return hashlib.sha256(intervention.model_dump_json().encode()).hexdigest()[:16]


def _check_earlier_decision(out_dir: Path, fingerprint: str, source: Path) -> None:
    """Refuse to overwrite the decision of another intervention that has the same name."""
    path = out_dir / DECISION_FILE
    if not path.is_file():
        return
    try:
        earlier = json.loads(path.read_text()).get("intervention_fingerprint")
    except (OSError, ValueError, AttributeError):
        earlier = None
    if earlier is not None and earlier != fingerprint:
        raise BpsflowError(
            f"name: {out_dir} holds the decision of an intervention of the same name whose "
            f"content differs; give this one another name, or move that folder away to "
            f"replace it", source=source)


def _tag(calibrated: Calibrated) -> str:
    """``[name]`` as text: a calibration's name printed as itself, not read as markup."""
    return escape(f"[{calibrated.name}]")


def week_hour_ends(first, last) -> pd.DatetimeIndex:
    """The hour-ending stamps of the days ``first``..``last``."""
    return pd.date_range(pd.Timestamp(first) + pd.Timedelta(hours=1),
                         pd.Timestamp(last) + pd.Timedelta(days=1), freq="h")


def _check_measured_week(measured: pd.DataFrame, outputs: list[str], first, last,
                         source: Path) -> None:
    """Refuse, before any run, measured data that do not cover the test week."""
    hour_ends = week_hour_ends(first, last)
    for output in outputs:
        if output not in measured.columns:
            raise BpsflowError(f"no column {output}, which outcome(s) of the intervention need "
                               f"for the test week", source=source)
        values = measured[output].reindex(hour_ends)
        if values.isna().any():
            gap = hour_ends[values.isna().to_numpy()]
            raise BpsflowError(f"{output} misses {len(gap)} hour(s) of the test week "
                               f"{first:%m-%d}..{last:%m-%d} (first: {gap[0]}); the week's "
                               "hours must all be measured", source=source)


def _summary(values: np.ndarray) -> dict[str, float]:
    values = np.asarray(values, dtype=float)
    q05, q50, q95 = np.quantile(values, [0.05, 0.5, 0.95])
    return {"mean": float(values.mean()), "q05": float(q05), "median": float(q50),
            "q95": float(q95)}


def decide(config: Config, calibration: Path, intervention_path: Path, *,
           scenarios: bool = False, measured_path: Path | None = None,
           jobs: int | None = None, show_progress: bool = True,
           console: Console | None = None) -> dict:
    """Run ``bpsflow decide`` (see the module docstring); returns what was written."""
    from bpsflow.calibration.command import SCENARIOS_DIR
    from bpsflow.decision.report import plot_correlation
    from bpsflow.files import write_json
    from bpsflow.measured import read_measured
    from bpsflow.simulation.backend import choose_backend

    console = console or Console()
    intervention = load_intervention(intervention_path, config)
    changed, added = intervention_config(config, intervention, Path(intervention_path))
    for name in added:
        console.print(f"intervention: {changed.parameter(name).description}")
    for line in _overlay_changes(config, changed):
        console.print(f"intervention: {line}", highlight=False)

    calibration = Path(calibration)
    folders = ([p for p in sorted((calibration / SCENARIOS_DIR).iterdir()) if p.is_dir()]
               if scenarios and (calibration / SCENARIOS_DIR).is_dir() else [calibration])
    if scenarios and folders == [calibration]:
        raise BpsflowError(f"--scenarios: no {SCENARIOS_DIR}/ folder in {calibration} (run "
                           f"'bpsflow calibrate --scenarios' first)")
    calibrations = [read_calibration(f, config) for f in folders]
    path = measured_path or calibrations[0].record.get("measured")
    if path is None:
        raise BpsflowError("--measured: the calibration does not record its measured file; "
                           "give it with --measured")
    data = read_measured(Path(path), config, required=sorted({o.output for o in intervention.outcomes}))
    for note in data.notes:
        console.print(f"[yellow]{escape(note)}[/yellow]", highlight=False)
    backend = choose_backend(config, console.print).name
    first, last = week_dates(intervention, config)
    _check_measured_week(data.frame, sorted({o.output for o in intervention.outcomes}), first,
                         last, Path(path))
    week = window_config(config, first, last)
    try:
        changed_week = window_config(changed, first, last)
    except BpsflowError as exc:
        raise BpsflowError(f"change.overlay: with the change, {exc.message}",
                           source=intervention_path) from None
    console.print(f"each draw runs {min(t.start for t in week.model.tests)}..{last:%m-%d}: the "
                  f"test week and its test's {max(t.warmup_days for t in week.model.tests)} "
                  "warm-up day(s)")
    fingerprint = intervention_fingerprint(intervention)
    for calibrated in calibrations:
        _check_earlier_decision(calibrated.folder / DECISION_DIR / intervention.name,
                                fingerprint, Path(intervention_path))
    records = []
    for calibrated in calibrations:
        out_dir = calibrated.folder / DECISION_DIR / intervention.name
        diagnostics = calibrated.record.get("diagnostics") or {}
        unconverged = diagnostics.get("converged") is False
        if unconverged:
            console.print(f"[yellow]{_tag(calibrated)} warning: this calibration's NUTS run did "
                          f"not converge ({'; '.join(diagnostics.get('reasons') or [])}); the "
                          "decision rests on its draws as they are[/yellow]", highlight=False)
        records.append(decide_one(week, calibrated, intervention, changed_week, data.frame, out_dir,
                                  backend=backend, jobs=jobs, show_progress=show_progress,
                                  console=console, source=Path(intervention_path),
                                  provenance={"measured": str(Path(path).resolve()),
                                              "measured_notes": list(data.notes),
                                              "calibration_converged": not unconverged}))
        for rule in records[-1]["rules"]:
            console.print(f"{_tag(calibrated)} {rule['name']}: p = "
                          f"{rule['underperformance_probability']:.3f}, "
                          f"{'implement' if rule['implement'] else 'do not implement'}, decision "
                          f"risk {rule['decision_risk']:.3f}")
        console.print(f"wrote {out_dir / DECISION_FILE}")
    summary: dict = {"decisions": records}
    if scenarios:
        from bpsflow.decision.risk import accuracy_risk_correlation, correlation_caveats

        accuracy, risks = _accuracy_and_risks(calibrations, records)
        summary["correlation"] = accuracy_risk_correlation(accuracy, risks)
        caveats = correlation_caveats(risks, min(r["outcomes_sampled"] for r in records))
        for caveat in caveats:
            console.print(f"[yellow]correlation: {caveat}[/yellow]", highlight=False)
        out = calibration / DECISION_DIR / intervention.name
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "correlation.json", {"scenarios": [c.name for c in calibrations],
                                              "accuracy": accuracy, "risks": risks,
                                              "pearson": summary["correlation"],
                                              "caveats": caveats})
        summary["correlation_figure"] = str(plot_correlation(summary["correlation"],
                                                             out / "accuracy_vs_risk.png"))
        console.print(f"wrote {out / 'correlation.json'} and {summary['correlation_figure']}")
    return summary


def _accuracy_and_risks(calibrations: list[Calibrated], records: list[dict]):
    """Held-out accuracy of each scenario's physical re-run and its decision risks (Figure 4.11)."""
    accuracy: dict[str, list[float]] = {}
    risks: dict[str, list[float]] = {}
    for k, (calibrated, record) in enumerate(zip(calibrations, records)):
        for row in calibrated.record.get("heldout", []):
            if row.get("model") != "bayes_physical" or row.get("resolution") != "hourly":
                continue
            for metric in ("cv_rmse", "nmcrps"):
                if row.get(metric) is not None:
                    key = f"{metric}:{row['output']}"
                    accuracy.setdefault(key, [np.nan] * len(records))[k] = float(row[metric])
        for rule in record["rules"]:
            risks.setdefault(rule["name"], [np.nan] * len(records))[k] = rule["decision_risk"]
            for event in rule["events"]:
                key = f"{rule['name']}:{event['outcome']}"
                p = event["probability"]
                risks.setdefault(key, [np.nan] * len(records))[k] = float(decision_risk(p))
    return accuracy, risks
