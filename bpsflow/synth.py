"""Synthetic measurements from a "true" instance with known values (seed §3.3, Table 3.3).

The truth file names the perturbed value of any parameter (the others take
their distribution's median) and, optionally, the output sensor noise. Noise
bounds follow seed Table 3.3 and are read as three standard deviations
(seed §3.4.3: "assuming the range is equal to three times of the standard
deviation"): room temperature ±0.001 °C, heating/cooling power ±0.5 %.

``measured.csv`` has one row per hour-ending timestamp of every test window
and one column per configured output. With ``detailed=True`` the truth
instance also reports the detailed measurements of :mod:`bpsflow.detailed`
(``detailed.csv``, ``sensor_calibration.csv``, ``detailed.json``, and the
true values behind them in the ``detailed`` block of ``truth.json``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import yaml
from pydantic import Field, ValidationError

from bpsflow.config import Config, _format_location, parse_yaml
from bpsflow.errors import BpsflowError
from bpsflow.files import read_user_text, write_csv, write_json
from bpsflow.schema import StrictModel
from bpsflow.simulation.target_bounds import check_sample_values, check_weather_support
from bpsflow.weather import read_epw

MEASURED_FILE = "measured.csv"
TRUTH_FILE = "truth.json"
EQUIVALENT_TRUTH_FILE = "truth_equivalent.json"
#: What a synthesis writes in its folder (an earlier one's are moved aside first).
SYNTH_FILES = (MEASURED_FILE, TRUTH_FILE, EQUIVALENT_TRUTH_FILE, "detailed.csv",
               "sensor_calibration.csv", "detailed.json")


class Noise(StrictModel):
    """Sensor noise of one output: ``bound`` is 3 standard deviations.

    ``autocorrelation`` (in [0, 1), default 0: independent hours) is the lag-1
    coefficient φ of an AR(1) process for the hourly noise,
    ``e_t = φ e_(t-1) + sqrt(1 - φ²) z_t`` with ``z_t`` standard normal and
    ``e_0 = z_0``, so every hour keeps the standard deviation ``bound / 3``
    (a slowly drifting sensor rather than white noise). The process restarts
    at every gap in the timestamps (between test windows).

    ``increment`` (optional, output units) makes the output a cumulative meter
    read in fixed steps that restarts at midnight, as the source's heating meter
    (seed §4.3.3): within each day the noisy values are summed, the running
    total is read down to a whole number of increments, and each interval's
    value is the reading's advance. A day's total keeps its value to within one
    increment; single intervals can read 0 or a whole increment.
    """

    kind: Literal["absolute", "relative"]
    bound: float = Field(ge=0)
    autocorrelation: float = Field(default=0.0, ge=0.0, lt=1.0)
    increment: float | None = Field(default=None, gt=0)


class Truth(StrictModel):
    values: dict[str, float] = Field(default_factory=dict)
    noise: dict[str, Noise] = Field(default_factory=dict)
    seed: int = Field(default=0, ge=0, le=2**32 - 1)


def default_noise(unit: str) -> Noise:
    """Seed Table 3.3: ±0.001 °C for temperatures, ±0.5 % for powers."""
    if unit.strip().upper() in ("C", "°C", "DEGC"):
        return Noise(kind="absolute", bound=0.001)
    return Noise(kind="relative", bound=0.005)


def load_truth(path: Path, config: Config) -> Truth:
    """Read and check a truth file against the config's parameters and outputs."""
    path = Path(path)
    try:
        raw = parse_yaml(read_user_text(path, "a YAML truth file")) or {}
        truth = Truth.model_validate(raw)
    except yaml.YAMLError as exc:
        raise BpsflowError(f"not valid YAML: {exc}", source=path) from None
    except ValidationError as exc:
        first = exc.errors()[0]
        form = ""
        if isinstance(raw, dict) and ({"model", "parameters", "extends"} & set(raw)):
            form = (" (this looks like a config: a truth file holds 'seed', 'values: "
                    "{parameter: value}' and 'noise: {output: ...}')")
        raise BpsflowError(f"{_format_location(tuple(first['loc']), raw)}: {first['msg']}{form}",
                           source=path) from None
    names = {p.name for p in config.parameters}
    for name, value in truth.values.items():
        if name not in names:
            raise BpsflowError(f"values.{name}: not a parameter of the config "
                               f"(expected one of {sorted(names)})", source=path)
        sequences = getattr(config.parameter(name).distribution, "sequences", None)
        if sequences is not None and (value != int(value) or not 0 <= value < sequences):
            raise BpsflowError(f"values.{name}: {value:g} is not a sequence index of its sampler "
                               f"(expected an integer 0..{sequences - 1})", source=path)
    for name in truth.noise:
        if name not in config.outputs:
            raise BpsflowError(f"noise.{name}: not an output of the config "
                               f"(expected one of {sorted(config.outputs)})", source=path)
    return truth


def truth_sample(config: Config, truth: Truth) -> dict[str, float]:
    """Every parameter's true value: the given ones, the rest at their median."""
    return {p.name: float(truth.values.get(p.name, p.distribution.nominal))
            for p in config.parameters}


def add_noise(values: np.ndarray, noise: Noise, rng: np.random.Generator,
              starts: np.ndarray | None = None) -> np.ndarray:
    """Gaussian sensor noise with standard deviation ``bound / 3`` (absolute or relative).

    Parameters
    ----------
    values : ndarray
        The true hourly values, in time order.
    noise : Noise
        Bound (3 standard deviations) and lag-1 autocorrelation of the noise.
    rng : Generator
        The random stream (one standard normal draw per value, whatever the
        autocorrelation, so the stream's later use does not depend on it).
    starts : ndarray of int, optional
        Positions where a new run of consecutive hours begins (the AR(1)
        process restarts there); default: one run.
    """
    std = noise.bound / 3.0
    scale = std if noise.kind == "absolute" else std * np.abs(values)
    return values + ar1_noise(rng.standard_normal(values.shape), noise.autocorrelation,
                              starts) * scale


def ar1_noise(innovations: np.ndarray, autocorrelation: float,
              starts: np.ndarray | None = None) -> np.ndarray:
    """Unit-variance AR(1) noise from standard normal ``innovations``.

    ``e_0 = z_0`` and ``e_t = φ e_(t-1) + sqrt(1 - φ²) z_t`` within each run
    beginning at ``starts`` (stationary from the first value); φ = 0 returns
    the innovations unchanged.
    """
    if autocorrelation == 0.0 or innovations.size == 0:
        return innovations
    from scipy.signal import lfilter

    phi = float(autocorrelation)
    gain = np.sqrt(1.0 - phi * phi)
    bounds = sorted({0, *(int(s) for s in (starts if starts is not None else ())),
                     len(innovations)})
    out = np.empty_like(innovations, dtype=float)
    for begin, end in zip(bounds[:-1], bounds[1:]):
        if end <= begin:
            continue
        out[begin] = innovations[begin]
        if end - begin > 1:
            out[begin + 1:end], _ = lfilter([gain], [1.0, -phi], innovations[begin + 1:end],
                                            zi=[phi * innovations[begin]])
    return out


def metered(values: np.ndarray, timestamps: pd.DatetimeIndex, increment: float,
            step: pd.Timedelta) -> np.ndarray:
    """Interval values as a cumulative meter read in ``increment`` steps and reset at midnight.

    Parameters
    ----------
    values : ndarray
        Consumption per interval (e.g. kWh per 15 minutes), in time order.
    timestamps : DatetimeIndex
        Interval-ending stamps; an interval belongs to the day it starts in.
    increment : float
        The meter's reading step, in the values' unit.
    step : Timedelta
        The interval length.

    Returns
    -------
    ndarray
        The advance of ``increment * floor(running daily total / increment)``
        over each interval.
    """
    values = np.asarray(values, dtype=float)
    days = (pd.DatetimeIndex(timestamps) - step).normalize()
    out = np.empty_like(values)
    for day in pd.unique(days):
        mine = np.flatnonzero(days == day)
        reading = np.floor(np.cumsum(values[mine]) / increment + 1e-9) * increment
        out[mine] = np.diff(reading, prepend=0.0)
    return out


def applied_noise(config: Config, truth: Truth, output: str) -> Noise:
    """The sensor noise ``synth`` adds to ``output``: the truth's own, else the unit's default."""
    return truth.noise.get(output) or default_noise(config.outputs[output].unit)


def measurements_from_outputs(config: Config, outputs: pd.DataFrame, truth: Truth) -> pd.DataFrame:
    """Wide, noisy measurements of the config's outputs from a truth instance's tidy outputs."""
    outputs = outputs[outputs["output"].isin(list(config.outputs))]
    wide = (outputs.drop_duplicates(["timestamp", "output"])
            .pivot(index="timestamp", columns="output", values="value").sort_index())
    rng = np.random.default_rng(truth.seed)
    steps = np.diff(wide.index.to_numpy())
    step = pd.Timedelta(np.median(steps)) if len(steps) else pd.Timedelta(hours=1)
    starts = np.flatnonzero(steps != step.to_timedelta64()) + 1
    for output in wide.columns:
        noise = applied_noise(config, truth, output)
        wide[output] = add_noise(wide[output].to_numpy(), noise, rng, starts)
        if noise.increment is not None:
            wide[output] = metered(wide[output].to_numpy(), wide.index, noise.increment, step)
    wide.columns.name = None
    return wide


def truth_notes(config: Config, truth: Truth) -> list[str]:
    """Notes for true values outside what the config's distributions can draw.

    Allowed (a truth beyond the prior tests how a calibration fails), but a
    prior that excludes the truth cannot cover it, so it is said.
    """
    from bpsflow.distributions import Constant, Discrete, Sampler

    notes = []
    for name, value in truth.values.items():
        distribution = config.parameter(name).distribution
        if isinstance(distribution, Sampler):
            continue
        if isinstance(distribution, Constant):
            if value != distribution.value:
                notes.append(f"values.{name}: {value:g} replaces the constant "
                             f"{distribution.value:g} of the config; every instance of a design "
                             f"keeps {distribution.value:g}, so no calibration can move it")
            continue
        if isinstance(distribution, Discrete):
            if not np.isclose(distribution.values, value).any():
                notes.append(f"values.{name}: {value:g} is none of its distribution's values "
                             f"({', '.join(f'{v:g}' for v in distribution.values)}); a design "
                             f"draws only those, so no calibration can reach it")
            continue
        low, high = (float(v) for v in distribution.ppf(np.array([0.0, 1.0])))
        if np.isfinite(low) and value < low or np.isfinite(high) and value > high:
            notes.append(f"values.{name}: {value:g} lies outside its distribution's "
                         f"{low:g}..{high:g}; a calibration with this prior cannot cover it")
    return notes


def synthesize(config: Config, truth: Truth, out_dir: Path, backend: str | None = None,
               detailed: bool = False) -> Path:
    """Run the truth instance and write ``measured.csv`` and ``truth.json`` into ``out_dir``.

    With ``detailed`` the same run also reports the detailed measurements over
    every run period's whole span (see :func:`write_detailed_measurements`).
    """
    from bpsflow.simulation.backend import choose_backend
    from bpsflow.simulation.ensemble import console, simulate_samples
    from bpsflow.simulation.rundir import move_aside

    out_dir.mkdir(parents=True, exist_ok=True)
    every_output = sorted(config.outputs)
    full = config.model_copy(deep=True)
    for test in full.model.tests:
        test.outputs = every_output
    if detailed:
        from bpsflow.detailed import add_detailed_outputs

        add_detailed_outputs(full)
    full.source = config.source
    sample = truth_sample(config, truth)
    if backend is not None:
        full.model.backend = backend
    simulator = choose_backend(full, console.print)
    frame = pd.DataFrame([sample], index=pd.Index([0], name="instance"))
    # A true value outside what EnergyPlus accepts (a reflectance of 5) is refused, as for
    # any drawn sample, rather than simulated silently.
    check_sample_values(full, frame, "the truth values")
    # a weather perturbation is bounded by the EPW's valid ranges, as for a design
    check_weather_support(full, read_epw(full.model.weather).columns, sample)
    try:
        # The truth draws from the run directory's boundary sequences, like its ensemble.
        outputs = simulate_samples(full, frame, out_dir / "simulation", simulator,
                                   sequences_dir=config.run_dir.resolve(), what="truth runs")
    except BpsflowError as exc:
        raise BpsflowError(f"the truth instance failed: {exc}") from None
    outputs = outputs.assign(instance="truth")
    backend = simulator.name
    measured = measurements_from_outputs(config, outputs, truth)
    # everything that can fail is computed before the earlier data are moved aside
    detailed_parts = detailed_measurements(config, sample, outputs, truth.seed) if detailed \
        else None
    path = out_dir / MEASURED_FILE
    # earlier synthetic data (perhaps of another truth) are kept, not overwritten
    earlier = move_aside(out_dir, SYNTH_FILES) if path.exists() else None
    if earlier is not None:
        console.print(f"the earlier synthetic data in {out_dir} were moved to {earlier}",
                      highlight=False)
    write_csv(measured, path, index_label="timestamp", float_format="%.6g")
    # every measured output's noise as applied, the defaults too: the record alone says
    # what was added to the measurements
    record = {"values": sample,
              "noise": {output: applied_noise(config, truth, output).model_dump()
                        for output in measured.columns},
              "noise_defaulted": sorted(set(measured.columns) - set(truth.noise)),
              "seed": truth.seed, "backend": backend}
    if detailed_parts is not None:
        from bpsflow.detailed import write_detailed

        readings, calibration, metadata, record["detailed"] = detailed_parts
        write_detailed(out_dir, readings, calibration, metadata)
    write_json(out_dir / TRUTH_FILE, record)
    return path


def write_equivalent_truth(config: Config, truth: Truth, simpler: Config, out_dir: Path) -> Path:
    """Write ``truth_equivalent.json``: the truth's values as ``simpler``'s model can hold them.

    See :mod:`bpsflow.equivalent_truth`; pass the file to ``calibrate --truth``
    to judge a prototype-room calibration against what it can recover.
    """
    from bpsflow.equivalent_truth import equivalent_values

    found = equivalent_values(config, truth_sample(config, truth), simpler)
    path = out_dir / EQUIVALENT_TRUTH_FILE
    write_json(path, {"values": found.values, "how": found.how,
                      "truth": str(out_dir / TRUTH_FILE), "truth_config": str(config.source),
                      "config": str(simpler.source)})
    return path


def write_detailed_measurements(config: Config, sample: dict[str, float], outputs: pd.DataFrame,
                                seed: int, out_dir: Path) -> dict:
    """Turn the truth instance's detailed outputs into sensor readings (seed §3.4.3–3.5).

    Writes ``detailed.csv``, ``sensor_calibration.csv`` and ``detailed.json``
    into ``out_dir`` (see :func:`detailed_measurements`) and returns the true
    values behind them.
    """
    from bpsflow import detailed as d

    readings, calibration, metadata, true = detailed_measurements(config, sample, outputs, seed)
    d.write_detailed(out_dir, readings, calibration, metadata)
    return true


def detailed_measurements(config: Config, sample: dict[str, float], outputs: pd.DataFrame,
                          seed: int) -> tuple[pd.DataFrame, pd.DataFrame, dict, dict]:
    """The detailed sensor readings of the truth instance, computed before anything is written.

    The sensor errors, the readings and the calibration campaign each get
    their own random stream derived from the truth seed (``measured.csv``
    keeps the seed's own stream, so it does not change).

    Returns
    -------
    tuple
        The readings, the sensor calibration table, the metadata
        (``detailed.json``) and the true values a refinement must not read
        (the ``detailed`` block of ``truth.json``): each temperature sensor's
        bias and std, per surface class the true α and n of h = α|ΔT|^n, the
        gradient, the ground reflectance, the glazing transmittance and the
        boundary temperatures.
    """
    from bpsflow import detailed as d

    geometry = d.cell_geometry(config)
    timestamps = pd.DatetimeIndex(sorted(outputs.loc[
        outputs["output"].isin(list(d.OTHER_OUTPUTS)), "timestamp"].unique()))
    boundary_c = d.true_boundary_temperatures(config, sample, timestamps)
    true = d.true_detailed(outputs, boundary_c, geometry)
    errors = d.draw_sensor_errors(true.columns, [seed, 1])
    readings = d.sensor_readings(true, errors, [seed, 2])
    calibration = d.calibration_campaign(errors, [seed, 3])
    return (readings, calibration, d.detailed_metadata(config, geometry, calibration),
            d.true_values(config, sample, errors, boundary_c))
