"""Calibration parameters, the design over them, and observations paired with simulations.

KOH calibration (seed eq. 19) needs two data sets on the same footing:

* **simulations** ``η(x, t)``: a Latin hypercube over the calibration
  parameters θ (the config's non-constant parameters, seed §4.3.3), each run
  over the whole calibration period with every other parameter at its nominal
  value;
* **field observations** ``y(x)``: the measured outputs over the evaluated
  days of the tests.

Both are aggregated to the scenario's resolution (daily means or hourly
values) and paired row by row: one row per (time, output), with the
simulated value of every run and the variable inputs ``x`` of that row
(weather aggregates, hour of day, weekend, setpoint schedule and an
output-type indicator so several outputs are pooled in one model, seed
§4.3.3, Table 4.2). The last ``holdout_days`` days are held out for testing
(seed §4.3.5: four weeks calibrate, the last week tests).

The unit design ``u`` in (0, 1)^k is kept beside the parameter values: the
emulator and the sampler work on ``u`` (the prior's CDF of θ), so every
calibration parameter has a uniform prior there whatever its distribution.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field, replace
from datetime import timedelta
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.alignment import align
from bpsflow.calibration.settings import DEFAULT_VARIABLE_INPUTS, CalibrationSettings, Scenario
from bpsflow.config import Config, Parameter, Test, config_fingerprint, test_dates
from bpsflow.distributions import Constant, Discrete, Empirical, Sampler
from bpsflow.errors import BpsflowError
from bpsflow.files import read_parquet, write_parquet, write_text_atomic
from bpsflow.sampling import latin_hypercube_unit
from bpsflow.simulation.setpoints import COOLING_OFF_C, HEATING_OFF_C, day_setpoints

DESIGN_DIR = "design"
#: In a run directory: the config fingerprint of the runs it holds.
CONFIG_FINGERPRINT_FILE = "config_fingerprint.txt"

# ppf(0) and ppf(1) are infinite for unbounded marginals.
_UNIT_EPS = 1e-9


# ---------------------------------------------------------------------------
# Calibration parameters


def calibration_parameters(config: Config, settings: CalibrationSettings,
                           key: str = "calibration.parameters") -> list[Parameter]:
    """The calibration parameters θ, in config order.

    ``settings.parameters`` when given, else every parameter whose
    distribution is not ``constant`` (the inputs screening kept, seed
    §4.3.3). ``key`` is the config key the messages name.

    Raises
    ------
    BpsflowError
        When a named parameter does not exist, or a calibration parameter has
        a distribution without a density (sampler, discrete, empirical).
    """
    by_name = {p.name: p for p in config.parameters}
    if settings.parameters is not None:
        for i, name in enumerate(settings.parameters):
            if name not in by_name:
                raise BpsflowError(f"{key}[{i}]: '{name}' is not a parameter "
                                   f"of the config", source=config.source)
        wanted = set(settings.parameters)
        chosen = [p for p in config.parameters if p.name in wanted]
    else:
        chosen = [p for p in config.parameters if not isinstance(p.distribution, Constant)]
    if not chosen:
        raise BpsflowError(f"{key.split('.')[0]}: no parameters to fit: every parameter is "
                           f"constant; leave the inputs to fit uncertain (or name them in "
                           f"{key})", source=config.source)
    for p in chosen:
        if isinstance(p.distribution, (Sampler, Discrete, Empirical, Constant)):
            raise BpsflowError(
                f"parameters ({p.name}).distribution: a fitted parameter ({key}) needs a continuous "
                f"distribution (uniform, normal, beta, lognormal, triangular), got "
                f"'{p.distribution.type}'; give it one of those, or leave it out of "
                f"{key}", source=config.source)
    return chosen


def nominal_sample(config: Config) -> dict[str, float]:
    """Every parameter at its nominal value (a constant's value, else the median)."""
    return {p.name: float(p.distribution.nominal) for p in config.parameters}


def unit_to_values(unit: np.ndarray, parameters: list[Parameter]) -> np.ndarray:
    """Map unit-cube values ``u`` (prior CDF) of θ to parameter values, column by column."""
    unit = np.clip(np.atleast_2d(np.asarray(unit, dtype=float)), _UNIT_EPS, 1 - _UNIT_EPS)
    return np.column_stack([p.distribution.ppf(unit[:, j]) for j, p in enumerate(parameters)])


def values_to_unit(values: np.ndarray, parameters: list[Parameter]) -> np.ndarray:
    """Inverse of :func:`unit_to_values`: the prior CDF of each θ value."""
    values = np.atleast_2d(np.asarray(values, dtype=float))
    return np.column_stack([p.distribution.scipy().cdf(values[:, j])
                            for j, p in enumerate(parameters)])


def samples_frame(config: Config, parameters: list[Parameter], unit: np.ndarray,
                  first_instance: int = 0) -> pd.DataFrame:
    """Run samples: θ from ``unit`` (rows), every other parameter at its nominal value."""
    values = unit_to_values(unit, parameters)
    base = nominal_sample(config)
    frame = pd.DataFrame([base] * len(values),
                         index=pd.RangeIndex(first_instance, first_instance + len(values),
                                             name="instance"))
    for j, p in enumerate(parameters):
        frame[p.name] = values[:, j]
    return frame


def design_unit(settings: CalibrationSettings, n_parameters: int) -> np.ndarray:
    """The Latin hypercube over θ on the unit cube, ``(runs, k)`` (SALib)."""
    return latin_hypercube_unit(settings.design.runs, n_parameters, settings.design.seed)


# ---------------------------------------------------------------------------
# Running the design


def run_samples(config: Config, samples: pd.DataFrame, run_dir: Path, *, backend: str,
                jobs: int | None = None, fresh: bool = False, show_progress: bool = True
                ) -> pd.DataFrame:
    """Run ``samples`` in ``run_dir`` (resuming finished instances) and return tidy results.

    A run directory holding a different design, or runs of another model,
    parameters, outputs or tests (other days: :func:`bpsflow.config.config_fingerprint`),
    is cleared first: instances are recognised by number only, so old results
    must not mix with new samples.
    ``fresh`` always clears it.

    Raises
    ------
    BpsflowError
        When instances failed (their errors are in ``run_dir/manifest.parquet``).
    """
    from bpsflow.boundary import ensure_sequences
    from bpsflow.sampling import SAMPLES_FILE
    from bpsflow.simulation.backend import get_backend
    from bpsflow.simulation.ensemble import run_config, run_ensemble
    from bpsflow.simulation.rundir import read_results

    run_dir = Path(run_dir).resolve()
    previous = run_dir / SAMPLES_FILE
    marker = run_dir / CONFIG_FINGERPRINT_FILE
    fingerprint = config_fingerprint(config)
    if run_dir.exists() and (
            fresh or not previous.is_file() or not marker.is_file()
            or marker.read_text().strip() != fingerprint
            or _simulates_another_model(config, run_dir, backend)
            or not _same_samples(read_parquet(previous).set_index("instance"), samples)):
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_parquet(samples.reset_index(), previous, index=False)
    write_text_atomic(marker, fingerprint + "\n")
    cfg = run_config(config, run_dir, backend)
    ensure_sequences(cfg)
    summary = run_ensemble(cfg, samples, get_backend(backend), show_progress=show_progress,
                           jobs=jobs)
    if summary.failed:
        raise BpsflowError(f"{summary.failed} of {summary.total} calibration runs failed in "
                           f"{run_dir}: {summary.first_error}")
    return read_results(run_dir)


def _simulates_another_model(config: Config, run_dir: Path, backend: str) -> bool:
    """Whether ``run_dir``'s runs simulated other model files, tests, outputs or backend."""
    from bpsflow.design_record import read_simulation_record, simulation_inputs

    record = read_simulation_record(run_dir)
    return record is not None and (record["inputs"] != simulation_inputs(config)
                                   or record.get("backend") not in (None, backend))


def _same_samples(old: pd.DataFrame, new: pd.DataFrame) -> bool:
    if old.shape != new.shape or list(old.columns) != list(new.columns) \
            or not old.index.equals(new.index):
        return False
    return bool(np.allclose(old.to_numpy(dtype=float), new.to_numpy(dtype=float),
                            rtol=1e-12, atol=1e-12))


# ---------------------------------------------------------------------------
# Observations paired with simulations


@dataclass
class Paired:
    """Observations and simulations of the same rows at one resolution.

    Attributes
    ----------
    rows : DataFrame
        One row per (time, output): ``time`` (the day for daily rows, the
        hour-ending timestamp for hourly rows), ``output``, ``test``, ``split``
        (``calibration`` or ``heldout``).
    observed : ndarray, shape (n,)
        Measured values, in the output's unit.
    simulated : ndarray, shape (n, runs)
        Each run's value of the row, in the output's unit.
    instances : ndarray, shape (runs,)
        Instance numbers of the runs (columns of ``simulated``).
    resolution : str
        ``daily`` or ``hourly``.
    """

    rows: pd.DataFrame
    observed: np.ndarray
    simulated: np.ndarray
    instances: np.ndarray
    resolution: str
    notes: list[str] = field(default_factory=list)

    def subset(self, mask: np.ndarray) -> Paired:
        mask = np.asarray(mask)
        return replace(self, rows=self.rows[mask].reset_index(drop=True),
                       observed=self.observed[mask], simulated=self.simulated[mask])

    def split(self, name: str) -> Paired:
        return self.subset((self.rows["split"] == name).to_numpy())

    def runs(self, columns: np.ndarray) -> Paired:
        """Keep only the runs (columns) selected by ``columns`` (indices or mask)."""
        return replace(self, simulated=self.simulated[:, columns],
                       instances=self.instances[columns])


def system_of(config: Config, output: str) -> str | None:
    """``heating`` / ``cooling`` for an ideal-loads rate output, else None (a state variable)."""
    variable = (config.outputs[output].variable or config.outputs[output].meter or "").upper()
    if "HEATING" in variable:
        return "heating"
    if "COOLING" in variable:
        return "cooling"
    return None


def hourly_setpoints(config: Config, hours: pd.DatetimeIndex) -> tuple[np.ndarray, np.ndarray]:
    """Heating and cooling setpoints (°C) in force during each hour-ending ``hours``.

    Days outside every test float (off setpoints), like the simulations.
    """
    by_day = {}
    for test in config.model.tests:
        first, _, last = test_dates(test, config.model.year)
        for d in range((last - first).days + 1):
            by_day[first + timedelta(days=d)] = test
    starts = hours - pd.Timedelta(hours=1)
    heating = np.empty(len(hours))
    cooling = np.empty(len(hours))
    cache: dict = {}
    for i, start in enumerate(starts):
        test = by_day.get(start.date())
        key = None if test is None else test.name
        if key not in cache:
            cache[key] = [_profile(p) for p in day_setpoints(test)]
        heating[i] = cache[key][0][start.hour]
        cooling[i] = cache[key][1][start.hour]
    return heating, cooling


def _profile(steps: list[tuple[int, float]]) -> np.ndarray:
    day = np.empty(24)
    lower = 0
    for until, value in steps:
        day[lower:until] = value
        lower = until
    return day


def pair(config: Config, results: pd.DataFrame, measured: pd.DataFrame, outputs: list[str],
         resolution: str, holdout_days: int, idle_fraction: float = 0.0,
         measured_source: Path | str | None = None,
         heldout_window: tuple[pd.Timestamp, pd.Timestamp] | None = None) -> Paired:
    """Pair measured and simulated values of ``outputs`` at ``resolution``.

    Every test that reports an output contributes its evaluated days; the
    last ``holdout_days`` days (over all tests) are the held-out split, or
    the days of ``heldout_window`` (first, last; another pairing's held-out
    days, so that every output is judged on the days a calibration held out).
    Heating (cooling) rate rows are kept only while that system is scheduled
    on and the measured value is above ``idle_fraction`` of its mean.

    Raises
    ------
    BpsflowError
        From :func:`bpsflow.alignment.align` (missing columns or hours), or
        when no test reports an output, or no calibration days remain.
    """
    pieces = []
    for output in outputs:
        tests = [t for t in config.model.tests if output in t.outputs]
        if not tests:
            raise BpsflowError(f"calibration: output '{output}' is not an output of any test in "
                               f"model.tests", source=config.source)
        pieces += [(test, output, align(config, results, measured, test, output, measured_source))
                   for test in tests]
    # runs that finished every test (a failed run lacks some)
    instances = pieces[0][2].instances
    for _, _, aligned in pieces[1:]:
        instances = np.intersect1d(instances, aligned.instances)
    instances = np.sort(instances)
    frames, observed, simulated = [], [], []
    for test, output, aligned in pieces:
        columns = pd.Index(aligned.instances).get_indexer(instances)
        frame, obs, sim = _aggregate(config, test, output, aligned.timestamps,
                                     aligned.observed, aligned.ensemble[:, columns], resolution)
        frames.append(frame)
        observed.append(obs)
        simulated.append(sim)
    rows = pd.concat(frames, ignore_index=True)
    observed_all = np.concatenate(observed)
    simulated_all = np.concatenate(simulated, axis=0)
    day = row_days(rows, resolution)
    last_day = day.max()
    if heldout_window is None:
        first_heldout = last_day - pd.Timedelta(days=holdout_days - 1)
        held = day >= first_heldout
    else:
        held = (day >= heldout_window[0]) & (day <= heldout_window[1])
    rows["split"] = np.where(held, "heldout", "calibration")
    if not (rows["split"] == "calibration").any():
        raise BpsflowError(f"calibration.holdout_days: holding out {holdout_days} days leaves no "
                           f"calibration days (evaluated days end {last_day:%m-%d})",
                           source=config.source)
    counts = rows.loc[rows["split"] == "calibration", "output"].value_counts()
    # (a re-run of the held-out days, holdout_days 0, is scored, not fitted)
    few = [o for o in pd.unique(rows["output"]) if counts.get(o, 0) < 2] if holdout_days else []
    if few:
        # NMBE and CV(RMSE) divide by n - 1 (seed eq. 1-2): one value fits nothing
        raise BpsflowError(f"calibration.holdout_days: holding out {holdout_days} days leaves "
                           f"{', '.join(f'{o}: {counts.get(o, 0)}' for o in few)} {resolution} "
                           f"calibration value(s); expected at least 2 per output (hold out "
                           f"fewer days, or use hourly resolution)", source=config.source)
    paired = Paired(rows=rows, observed=observed_all, simulated=simulated_all,
                    instances=np.asarray(instances), resolution=resolution)
    return _drop_idle(config, paired, idle_fraction)


def row_days(rows: pd.DataFrame, resolution: str) -> pd.Series:
    """The day of each row (an hourly row ending at midnight belongs to the day before)."""
    if resolution == "daily":
        return rows["time"].dt.floor("D")
    return (rows["time"] - pd.Timedelta(hours=1)).dt.floor("D")


def resimulated(paired: Paired, reruns: Paired) -> Paired:
    """``paired``'s rows with the simulations of ``reruns`` instead of its own.

    ``reruns`` pairs other runs over days that include ``paired``'s (e.g. a
    :func:`bpsflow.config.window_config` of the same config); its rows are
    matched by test, output and time, so ``paired``'s selection of rows
    (held-out split, idle rows dropped) is kept.
    """
    key = ["test", "output", "time"]
    where = pd.MultiIndex.from_frame(reruns.rows[key]).get_indexer(
        pd.MultiIndex.from_frame(paired.rows[key]))
    if (where < 0).any():
        missing = paired.rows.iloc[int(np.flatnonzero(where < 0)[0])]
        raise BpsflowError(f"the re-runs have no {missing['output']} value at {missing['time']} "
                           f"(test {missing['test']})")
    return replace(paired, simulated=reruns.simulated[where], instances=reruns.instances)


def _aggregate(config: Config, test: Test, output: str, hours: pd.DatetimeIndex,
               observed: np.ndarray, ensemble: np.ndarray, resolution: str
               ) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    heating, cooling = hourly_setpoints(config, hours)
    # a test on the model's own controls has no schedule the tool knows: only the idle
    # rule (measured value near zero) drops its heating/cooling rows
    system = None if test.mode == "model" else system_of(config, output)
    on = np.ones(len(hours), bool) if system is None else \
        (heating > HEATING_OFF_C) if system == "heating" else (cooling < COOLING_OFF_C)
    if resolution == "hourly":
        frame = pd.DataFrame({"time": hours, "output": output, "test": test.name, "on": on})
        return frame, observed, ensemble
    days = (hours - pd.Timedelta(hours=1)).floor("D")
    groups = pd.Index(days).unique()
    codes = pd.Index(groups).get_indexer(days)
    counts = np.bincount(codes, minlength=len(groups))
    obs = np.bincount(codes, weights=observed, minlength=len(groups)) / counts
    sim = np.stack([np.bincount(codes, weights=ensemble[:, j], minlength=len(groups))
                    for j in range(ensemble.shape[1])], axis=1) / counts[:, None]
    on_day = np.bincount(codes, weights=on.astype(float), minlength=len(groups)) > 0
    frame = pd.DataFrame({"time": groups, "output": output, "test": test.name, "on": on_day})
    return frame, obs, sim


def _drop_idle(config: Config, paired: Paired, idle_fraction: float) -> Paired:
    keep = paired.rows["on"].to_numpy().copy()
    for output in paired.rows["output"].unique():
        if system_of(config, output) is None:
            continue
        mine = (paired.rows["output"] == output).to_numpy() & keep
        if idle_fraction > 0 and mine.any():
            level = idle_fraction * float(np.mean(np.abs(paired.observed[mine])))
            keep &= ~((paired.rows["output"] == output).to_numpy()
                      & (np.abs(paired.observed) <= level))
    dropped = int((~keep).sum())
    out = paired.subset(keep)
    out.rows = out.rows.drop(columns="on")
    if dropped:
        out.notes.append(f"{dropped} heating/cooling row(s) dropped: system scheduled off or idle "
                         f"(measured value <= {idle_fraction:g} x its mean)")
    return out


def select_observations(paired: Paired, max_observations: int, seed: int) -> Paired:
    """Keep every held-out row and at most ``max_observations`` calibration rows.

    The kept calibration rows are a seeded random subset (in time order),
    spread evenly over the outputs.
    """
    calibration = np.flatnonzero((paired.rows["split"] == "calibration").to_numpy())
    if len(calibration) <= max_observations:
        return paired
    rng = np.random.default_rng(seed)
    outputs = paired.rows["output"].to_numpy()[calibration]
    groups = [calibration[outputs == o] for o in pd.unique(outputs)]
    quota = _quotas([len(g) for g in groups], max_observations)
    chosen = np.concatenate([rng.choice(g, q, replace=False) for g, q in zip(groups, quota)])
    keep = (paired.rows["split"] != "calibration").to_numpy().copy()
    keep[chosen] = True
    out = paired.subset(keep)
    out.notes = paired.notes + [f"calibration rows subsampled: {max_observations} of "
                                f"{len(calibration)} (seed {seed})"]
    return out


def _quotas(sizes: list[int], total: int) -> list[int]:
    """Split ``total`` over groups as evenly as their sizes allow."""
    quota = [0] * len(sizes)
    left = total
    open_groups = [i for i, s in enumerate(sizes) if s > 0]
    while left > 0 and open_groups:
        share = max(1, left // len(open_groups))
        for i in list(open_groups):
            take = min(share, sizes[i] - quota[i], left)
            quota[i] += take
            left -= take
            if quota[i] == sizes[i]:
                open_groups.remove(i)
            if left == 0:
                break
    return quota


# ---------------------------------------------------------------------------
# Variable inputs x


#: Weather variable inputs and the EPW column they average.
_EPW_COLUMN = {
    "outdoor_air_temperature": "dry_bulb_temperature",
    "global_horizontal_radiation": "global_horizontal_radiation",
    "direct_normal_radiation": "direct_normal_radiation",
    "diffuse_horizontal_radiation": "diffuse_horizontal_radiation",
    "wind_speed": "wind_speed",
}


def variable_input_names(scenario: Scenario) -> list[str]:
    """The scenario's variable inputs (its own list, else the resolution's defaults)."""
    return list(scenario.variable_inputs or DEFAULT_VARIABLE_INPUTS[scenario.resolution])


def variable_inputs(config: Config, rows: pd.DataFrame, resolution: str, names: list[str],
                    outputs: list[str]) -> pd.DataFrame:
    """Variable inputs ``x`` of each row (seed Table 4.2), from the weather file and schedules.

    Weather quantities are the EPW's hourly values averaged over the row's
    interval (the day, or the hour); ``*_24h`` average the 24 hours before
    it. ``output`` is the position of the row's output in ``outputs``.
    Inputs that do not apply (``hour_of_day`` at daily resolution) are
    skipped.

    Returns
    -------
    DataFrame
        One column per input, aligned with ``rows``.
    """
    from bpsflow.weather import epw_rows, read_epw

    epw = read_epw(config.model.weather)
    hours_per_row = 24 if resolution == "daily" else 1
    starts = rows["time"] if resolution == "daily" else rows["time"] - pd.Timedelta(hours=1)
    n_rows = epw.n_hours
    first_row = epw_rows(starts, n_rows)

    def mean_over(column: str, offset: int, length: int) -> np.ndarray:
        values = epw.columns[column]
        index = (first_row[:, None] + offset + np.arange(length)[None, :]) % n_rows
        return values[index].mean(axis=1)

    out: dict[str, np.ndarray] = {}
    for name in names:
        column = _EPW_COLUMN.get(name.removesuffix("_24h"))
        if column is not None:
            out[name] = mean_over(column, -24, 24) if name.endswith("_24h") else \
                mean_over(column, 0, hours_per_row)
        elif name.startswith("hour_of_day"):
            if resolution == "daily":
                continue
            hour = starts.dt.hour.to_numpy().astype(float)
            out[name] = {"hour_of_day": hour, "hour_of_day_sin": np.sin(2 * np.pi * hour / 24),
                         "hour_of_day_cos": np.cos(2 * np.pi * hour / 24)}[name]
        elif name == "weekend":
            out[name] = (starts.dt.dayofweek.to_numpy() >= 5).astype(float)
        elif name in ("setpoint_c", "setpoint_c_lag2"):
            out[name] = _setpoint_input(config, rows, starts, resolution,
                                        lag=2 * (name != "setpoint_c"))
        elif name == "output":
            out[name] = rows["output"].map({o: i for i, o in enumerate(outputs)}).to_numpy(float)
    return pd.DataFrame(out, index=rows.index)


def _setpoint_input(config: Config, rows: pd.DataFrame, starts: pd.Series, resolution: str,
                    lag: int) -> np.ndarray:
    """The setpoint of the controlling system in force (interval mean); NaN-free."""
    n = 24 if resolution == "daily" else 1
    hour_ends = (starts.to_numpy()[:, None] + np.timedelta64(1, "h")
                 + (np.arange(n) - lag).astype("timedelta64[h]")[None, :]).ravel()
    heating, cooling = hourly_setpoints(config, pd.DatetimeIndex(hour_ends))
    modes = {t.name: t.mode for t in config.model.tests}
    mode = np.repeat(rows["test"].map(modes).to_numpy(), n)
    value = np.where(mode == "heating", heating, np.where(mode == "cooling", cooling, np.nan))
    value[(value <= HEATING_OFF_C) | (value >= COOLING_OFF_C)] = np.nan
    value = value.reshape(-1, n)
    with np.errstate(invalid="ignore"):
        mean = np.nanmean(value, axis=1) if np.isfinite(value).any() else np.zeros(len(value))
    # a free-floating interval has no setpoint: the mean setpoint stands in for it
    fill = np.nanmean(mean) if np.isfinite(mean).any() else 0.0
    return np.where(np.isfinite(mean), mean, fill)
