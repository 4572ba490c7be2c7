"""Morris screening of the uncertain inputs (seed §3.4.8, Figure 3.3, Tables A.1–A.6).

The source screens its 148 inputs with a 10-level Morris design of about
``10 (k + 1)`` runs and analyses, per test, "the difference between predictions
and observations averaged over the three-day period of each test" (the
evaluated days after the warm-up). Inputs are ranked by the mean absolute
elementary effect mu*; the standard deviation sigma of the effects shows
non-linearity and interactions. The least influential inputs can then be
fixed at a nominal value (:func:`screened_config`).

Responses (:func:`window_responses`), per test and output, named
``<test>:<output>`` (e.g. ``I600-C-CT:cooling_power_w``):

``difference``
    mean over the evaluated hours of prediction minus measurement (the source's
    response). The measured mean is one number per test, the same for every
    instance, so its elementary effects are exactly those of ``raw``; it is
    offered for fidelity to the source.
``absolute``
    mean over the evaluated hours of |prediction − measurement|: a different
    response, whose effects say which inputs move the prediction towards or
    away from the measurements.
``raw``
    the mean prediction over the evaluated hours (needs no measured data).

Elementary effects follow SALib's definition exactly: on the grid
``x = j / (levels − 1)`` of each input's normalised range, a step of
``Δ = levels / (2 (levels − 1))`` (``levels / 2`` levels) changes the response by
``Δy`` and the effect is ``Δy / Δ``, in response units per unit of the
normalised input range. The design itself puts level ``j`` at the quantile
``(j + 0.5) / levels`` (:func:`bpsflow.sampling.morris_unit`), so unbounded
marginals stay finite; :func:`morris_indices` maps the quantiles back to the
grid before analysing. A response linear in the quantile ``u`` with slope
``c`` therefore has ``mu* = |c| (levels − 1) / levels``.

Files, all under ``<run_dir>/morris/`` (the LHS files in ``<run_dir>`` are
never touched)::

    morris_design.json     the settings the design was drawn with
    samples.parquet  design_unit.parquet  boundary_sequences.npz
    manifest.parquet  results.parquet  instances/
    sensitivity.csv        response, parameter, group, mu, mu_star, mu_star_conf, sigma, rank
    sensitivity_groups.csv response, group, mu_star_sum, mu_star_max, top_parameter, count
    figures/morris_<test>_<output>.png
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd
import yaml
from SALib.analyze import morris as salib_morris

from bpsflow.alignment import align, evaluation_hours
from bpsflow.config import Config, Parameter
from bpsflow.design_record import SIMULATION_FILE, changed_keys, simulation_inputs
from bpsflow.distributions import Constant
from bpsflow.errors import BpsflowError
from bpsflow.files import inside, jsonable, read_parquet, write_csv, write_json, write_text_atomic
from bpsflow.sampling import UNIT_DESIGN_FILE, Design, morris_unit, transform
from bpsflow.simulation.rundir import move_aside

MORRIS_DIR = "morris"
SETTINGS_FILE = "morris_design.json"
INDICES_FILE = "sensitivity.csv"
GROUPS_FILE = "sensitivity_groups.csv"
INDEX_COLUMNS = ["response", "parameter", "group", "mu", "mu_star", "mu_star_conf", "sigma",
                 "rank"]
GROUP_COLUMNS = ["response", "group", "mu_star_sum", "mu_star_max", "top_parameter", "count"]

ResponseKind = Literal["difference", "absolute", "raw"]
RESPONSE_KINDS: tuple[str, ...] = ("difference", "absolute", "raw")

# Files a Morris run directory holds; removed when the design is drawn again.
_RUN_FILES = ("samples.parquet", UNIT_DESIGN_FILE, "boundary_sequences.npz", "manifest.parquet",
              SIMULATION_FILE,
              "results.parquet", "config.resolved.yaml", INDICES_FILE, GROUPS_FILE, SETTINGS_FILE)


# Design ------------------------------------------------------------------

def varied_parameters(config: Config) -> list[Parameter]:
    """The parameters a Morris design steps: every one not held constant."""
    return [p for p in config.parameters if not isinstance(p.distribution, Constant)]


def check_levels(levels: int, where: str = "design.levels") -> None:
    """Morris steps are ``levels / 2`` levels, so ``levels`` must be even (and ≥ 2)."""
    if levels < 2 or levels % 2:
        raise BpsflowError(f"{where}: a Morris design needs an even number of levels ≥ 2 "
                           f"(each step moves levels/2 levels; the source uses 10), got {levels}")


def morris_config(config: Config, trajectories: int | None = None,
                  levels: int | None = None) -> Config:
    """A copy of ``config`` with a Morris design, running in ``<run_dir>/morris``."""
    morris = config.model_copy(deep=True)
    morris.source = config.source
    morris.design.method = "morris"
    if trajectories is not None:
        if trajectories < 2:
            raise BpsflowError(f"--trajectories: need at least 2 (sigma needs two elementary "
                               f"effects per input), got {trajectories}")
        morris.design.trajectories = trajectories
    if levels is not None:
        morris.design.levels = levels
    check_levels(morris.design.levels, "--levels" if levels is not None else "design.levels")
    morris.execution.run_dir = config.run_dir.resolve() / MORRIS_DIR
    return morris


def morris_design(config: Config, trajectories: int | None = None, levels: int | None = None,
                  random_state: int | None = None) -> Design:
    """Draw a Morris design of the config's non-constant parameters (SALib).

    Parameters
    ----------
    config : Config
    trajectories, levels : int, optional
        Override ``design.trajectories`` and ``design.levels`` (seed §3.4.8: 10 levels,
        about ``10 (k + 1)`` runs).
    random_state : int, optional
        Override ``design.seed``.

    Returns
    -------
    Design
        ``unit`` holds the stepped parameters' level mid-points ``(j + 0.5) / levels``;
        ``values`` every parameter (constant ones at their value), one row per run,
        ``trajectories * (k + 1)`` rows for ``k`` stepped parameters.
    """
    trajectories = trajectories or config.design.trajectories
    levels = levels or config.design.levels
    check_levels(levels)
    seed = config.design.seed if random_state is None else random_state
    varied = varied_parameters(config)
    if not varied:
        raise BpsflowError("parameters: no uncertain (non-constant) parameters to screen",
                           source=config.source)
    unit = morris_unit(varied, trajectories, levels, seed)
    index = pd.RangeIndex(len(unit), name="instance")
    unit_frame = pd.DataFrame(unit, columns=[p.name for p in varied], index=index)
    stepped = dict(zip(unit_frame.columns, transform(unit, varied).T))
    values = pd.DataFrame({p.name: stepped[p.name] if p.name in stepped
                           else np.full(len(unit), p.distribution.value)
                           for p in config.parameters}, index=index)
    return Design(unit=unit_frame, values=values, method="morris")


def design_settings(config: Config, backend: str) -> dict[str, Any]:
    """What a Morris run's results depend on: model, parameters, outputs, design, backend."""
    dumped = config.model_dump(mode="json", exclude={"execution", "validation", "calibration"})
    dumped["model"].pop("backend", None)
    for parameter in dumped["parameters"]:
        for key in ("group", "description", "provenance"):
            parameter.pop(key, None)
    design = config.design
    dumped["design"] = {"method": "morris", "levels": design.levels,
                        "trajectories": design.trajectories, "seed": design.seed}
    # files by content: an edited IDF or weather file is another design, drawn again
    dumped["simulation"] = simulation_inputs(config)
    dumped["backend"] = backend
    return dumped


def _differences(old: dict, new: dict) -> list[str]:
    changed = []
    for key in sorted(set(old) | set(new)):
        if old.get(key) == new.get(key):
            continue
        if key == "design" and isinstance(old.get(key), dict):
            changed += [f"design.{k} {old[key].get(k)} → {new[key].get(k)}"
                        for k in new[key] if old[key].get(k) != new[key].get(k)]
        elif key == "simulation" and isinstance(old.get(key), dict):
            changed += changed_keys(old[key], new.get(key) or {})
        elif key == "backend":
            changed.append(f"backend {old.get(key)} → {new.get(key)}")
        else:
            changed.append(key)
    return changed


def prepare_morris(config: Config, backend: str,
                   announce: Callable[[str], Any] = print) -> pd.DataFrame:
    """Make sure ``<run_dir>/morris`` holds the Morris design of ``config``'s settings.

    ``config`` is a :func:`morris_config`. An existing design drawn with the same
    settings is kept (its finished instances are reused); one drawn with other
    settings is discarded with its results (announced) and drawn again.

    Returns
    -------
    DataFrame
        The samples (indexed by instance) to run.
    """
    from bpsflow.boundary import ensure_sequences
    from bpsflow.sampling import read_samples, write_design

    run_dir = config.run_dir.resolve()
    # as write_json stores them, so that the comparison with the stored settings is like for like
    settings = jsonable(design_settings(config, backend))
    settings_path = run_dir / SETTINGS_FILE
    if (run_dir / "samples.parquet").is_file():
        old = json.loads(settings_path.read_text()) if settings_path.is_file() else {}
        if old == settings:
            ensure_sequences(config)
            return read_samples(run_dir)
        changed = _differences(old, settings) if old else ["(no record of its settings)"]
        instances = run_dir / "instances"
        finished = len(list(instances.glob("*"))) if instances.is_dir() else 0
        moved = move_aside(run_dir, [*_RUN_FILES, "instances", "figures"])
        announce(f"[yellow]the Morris design in {run_dir} was made with other settings "
                 f"({'; '.join(changed)}); drawing it again"
                 + (f"; its {finished} run instance(s) and results were moved to {moved}"
                    if finished else f"; the earlier design was moved to {moved}")
                 + "[/yellow]")
    design = morris_design(config)
    write_design(design, run_dir)
    ensure_sequences(config)
    write_text_atomic(run_dir / "config.resolved.yaml",
                      yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))
    write_json(settings_path, settings)
    return design.values


def read_unit_design(run_dir: Path) -> pd.DataFrame:
    """Read ``design_unit.parquet`` (indexed by instance)."""
    path = run_dir / UNIT_DESIGN_FILE
    if not path.is_file():
        raise BpsflowError(f"no Morris design in {run_dir} (expected {path})")
    return read_parquet(path).set_index("instance")


# Responses -----------------------------------------------------------------

def response_name(test: str, output: str) -> str:
    return f"{test}:{output}"


def _prediction_window(results: pd.DataFrame, test: str, output: str,
                       hours: pd.DatetimeIndex) -> pd.DataFrame:
    """Hours × instances of one test's output over its evaluated hours (NaN where missing)."""
    rows = results[(results["test"] == test) & (results["output"] == output)]
    wide = rows.pivot(index="timestamp", columns="instance", values="value").reindex(hours)
    if wide.shape[1] == 0 or wide.isna().all(axis=1).any():
        raise BpsflowError(f"the results have no values of '{output}' for some evaluated hours "
                           f"of test {test}: was the run finished with this config?")
    return wide


def window_responses(config: Config, results: pd.DataFrame,
                     measured: pd.DataFrame | None = None, kind: ResponseKind = "difference",
                     measured_source: Path | str | None = None) -> pd.DataFrame:
    """One response per test and output, averaged over the test's evaluated hours (seed §3.4.8).

    Parameters
    ----------
    config : Config
    results : DataFrame
        Tidy results (instance, test, output, timestamp, value).
    measured : DataFrame, optional
        Hour-ending measurements, one column per output; needed unless ``kind`` is ``raw``.
    kind : {'difference', 'absolute', 'raw'}
        ``difference``: mean of prediction − measurement; ``absolute``: mean of
        |prediction − measurement|; ``raw``: mean prediction. In the output's unit.
    measured_source : path, optional
        Named in error messages about the measured data.

    Returns
    -------
    DataFrame
        Indexed by instance, one column ``<test>:<output>`` per test and output; NaN
        for an instance that lacks hours of the window (a failed run).

    Raises
    ------
    BpsflowError
        For an unknown ``kind``, missing measurements, or measured data lacking a
        column or hours of a window (see :func:`bpsflow.alignment.align`).
    """
    if kind not in RESPONSE_KINDS:
        raise BpsflowError(f"--response: expected one of {', '.join(RESPONSE_KINDS)}, got '{kind}'")
    if kind != "raw" and measured is None:
        raise BpsflowError(f"--response {kind} compares predictions with measurements: give "
                           f"--measured FILE (or use --response raw)")
    instances = pd.Index(sorted(results["instance"].unique()), name="instance")
    columns = {}
    for test in config.model.tests:
        hours = evaluation_hours(test, config.model.year)
        for output in test.outputs:
            name = response_name(test.name, output)
            if kind == "raw":
                wide = _prediction_window(results, test.name, output, hours)
                columns[name] = wide.mean(axis=0, skipna=False)
                continue
            aligned = align(config, results, measured, test, output, measured_source)
            error = aligned.ensemble - aligned.observed[:, None]
            value = error.mean(axis=0) if kind == "difference" else np.abs(error).mean(axis=0)
            columns[name] = pd.Series(value, index=aligned.instances)
    return pd.DataFrame({name: series.reindex(instances) for name, series in columns.items()},
                        index=instances)


# Analysis ----------------------------------------------------------------

def grid_from_unit(unit_design: np.ndarray, levels: int) -> np.ndarray:
    """Map level mid-points ``(j + 0.5) / levels`` back to SALib's grid ``j / (levels − 1)``.

    Raises
    ------
    BpsflowError
        When a value is not a level mid-point (not a Morris design of ``levels`` levels).
    """
    unit_design = np.asarray(unit_design, dtype=float)
    level = np.rint(unit_design * levels - 0.5)
    if not np.allclose((level + 0.5) / levels, unit_design, rtol=0, atol=1e-9) \
            or level.min() < 0 or level.max() > levels - 1:
        raise BpsflowError(f"the unit design is not on the mid-points of a {levels}-level grid: "
                           f"was it drawn as a Morris design with {levels} levels?")
    return level / (levels - 1)


def check_trajectories(grid: np.ndarray, levels: int) -> int:
    """Check that ``grid`` is a Morris design; return its number of trajectories.

    Each trajectory has ``k + 1`` points and moves every input once by ±Δ,
    ``Δ = levels / (2 (levels − 1))``.
    """
    runs, k = grid.shape
    if runs % (k + 1):
        raise BpsflowError(f"a Morris design of {k} inputs has a multiple of {k + 1} runs; "
                           f"this one has {runs}")
    delta = levels / (2.0 * (levels - 1))
    steps = np.diff(grid.reshape(runs // (k + 1), k + 1, k), axis=1)
    moved = np.abs(steps) > 1e-9
    if not ((moved.sum(axis=2) == 1).all() and (moved.sum(axis=1) == 1).all()
            and np.allclose(np.abs(steps[moved]), delta)):
        raise BpsflowError(f"the design is not a Morris design of {levels} levels: every step "
                           f"must move exactly one input by {delta:.4g} and each input once per "
                           f"trajectory")
    return runs // (k + 1)


def morris_indices(parameters: Sequence[Parameter] | Sequence[str], unit_design: np.ndarray,
                   responses: pd.DataFrame, levels: int, seed: int = 0,
                   num_resamples: int = 1000, conf_level: float = 0.95) -> pd.DataFrame:
    """Morris indices mu, mu*, mu*_conf and sigma of every response (SALib.analyze.morris).

    Parameters
    ----------
    parameters : list of Parameter or of str
        The stepped inputs, in the unit design's column order (names, or parameters
        whose ``group`` is reported).
    unit_design : ndarray, shape (runs, k)
        The design's level mid-points (``design_unit.parquet``).
    responses : DataFrame
        ``runs`` rows in design order, one column per response; NaN marks a failed
        run, whose trajectory is left out of that response's analysis.
    levels : int
        The design's number of levels.
    seed : int
        Seed of the bootstrap behind ``mu_star_conf``.
    num_resamples, conf_level
        Bootstrap resamples and confidence level of ``mu_star_conf``.

    Returns
    -------
    DataFrame
        Tidy: response, parameter, group, mu, mu_star, mu_star_conf, sigma, rank
        (1 = largest mu* within the response), trajectories (the number analysed).
        Effects are in response units per unit of the normalised input range
        (SALib's definition, see the module notes).
    """
    names = [p if isinstance(p, str) else p.name for p in parameters]
    groups = ["other" if isinstance(p, str) else p.group for p in parameters]
    grid = grid_from_unit(unit_design, levels)
    if grid.shape[1] != len(names):
        raise BpsflowError(f"the design has {grid.shape[1]} columns but {len(names)} parameters "
                           f"were named")
    if len(responses) != len(grid):
        raise BpsflowError(f"{len(responses)} responses for a design of {len(grid)} runs")
    trajectories = check_trajectories(grid, levels)
    size = len(names) + 1
    frames = []
    for column in responses.columns:
        values = responses[column].to_numpy(dtype=float)
        complete = np.isfinite(values.reshape(trajectories, size)).all(axis=1)
        if complete.sum() < 2:
            raise BpsflowError(f"response {column}: only {int(complete.sum())} of {trajectories} "
                               f"trajectories are complete (failed runs); Morris needs at least 2")
        rows = np.repeat(complete, size)
        problem = {"num_vars": len(names), "names": names, "bounds": [[0.0, 1.0]] * len(names)}
        result = salib_morris.analyze(problem, grid[rows], values[rows], num_levels=levels,
                                      num_resamples=num_resamples, conf_level=conf_level,
                                      seed=seed)
        frame = pd.DataFrame({
            "response": column, "parameter": names, "group": groups,
            "mu": np.asarray(result["mu"], dtype=float),
            "mu_star": np.asarray(result["mu_star"], dtype=float),
            "mu_star_conf": np.asarray(result["mu_star_conf"], dtype=float),
            "sigma": np.asarray(result["sigma"], dtype=float),
        })
        frame = frame.sort_values("mu_star", ascending=False, kind="stable")
        frame["rank"] = np.arange(1, len(frame) + 1)
        frame["trajectories"] = int(complete.sum())
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def group_summary(indices: pd.DataFrame) -> pd.DataFrame:
    """Per response and parameter group: summed and largest mu*, the top parameter, the count."""
    rows = []
    for (response, group), frame in indices.groupby(["response", "group"], sort=False):
        top = frame.loc[frame["mu_star"].idxmax()]
        rows.append({"response": response, "group": group,
                     "mu_star_sum": float(frame["mu_star"].sum()),
                     "mu_star_max": float(top["mu_star"]), "top_parameter": top["parameter"],
                     "count": len(frame)})
    summary = pd.DataFrame(rows, columns=GROUP_COLUMNS)
    order = {r: i for i, r in enumerate(indices["response"].unique())}
    summary["_order"] = summary["response"].map(order)
    summary = summary.sort_values(["_order", "mu_star_sum"], ascending=[True, False])
    return summary.drop(columns="_order").reset_index(drop=True)


def write_tables(indices: pd.DataFrame, groups: pd.DataFrame, out_dir: Path) -> dict[str, Path]:
    """Write ``sensitivity.csv`` and ``sensitivity_groups.csv`` into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"indices": out_dir / INDICES_FILE, "groups": out_dir / GROUPS_FILE}
    write_csv(indices[INDEX_COLUMNS], paths["indices"], index=False, float_format="%.6g")
    write_csv(groups[GROUP_COLUMNS], paths["groups"], index=False, float_format="%.6g")
    return paths


def plot_all(config: Config, indices: pd.DataFrame, out_dir: Path,
             label_top: int = 10) -> list[Path]:
    """One mu*–sigma figure per response: ``out_dir/morris_<test>_<output>.png``."""
    from bpsflow.plots import plot_mu_star_sigma

    group_order = list(dict.fromkeys(p.group for p in config.parameters))
    paths = []
    for response, frame in indices.groupby("response", sort=False):
        output = response.split(":", 1)[1]
        paths.append(plot_mu_star_sigma(
            frame, inside(out_dir, f"morris_{response.replace(':', '_')}.png"), title=response,
            unit=config.outputs[output].unit, label_top=label_top, group_order=group_order))
    return paths


# Screening -------------------------------------------------------------------

def kept_parameters(indices: pd.DataFrame, top: int, ties: bool = False) -> list[str]:
    """The union over responses of each response's ``top`` inputs by mu* (mu* > 0 only).

    With ``ties``, a response also keeps every input whose mu* confidence interval
    reaches that of its ``top``-th input (``mu*_i + conf_i >= mu*_top - conf_top``):
    one its trajectories cannot tell apart from an input that is kept. Where mu*
    falls from a few large inputs into a flat tail, a plain cut at ``top`` fixes
    inputs as influential as the last one kept.
    """
    if top < 1:
        raise BpsflowError(f"--screen: expected a number of inputs to keep per response ≥ 1, "
                           f"got {top}")
    chosen = indices["rank"] <= top
    if ties:
        last = indices[chosen].sort_values("rank").groupby("response").tail(1)
        floor = (last["mu_star"] - last["mu_star_conf"]).set_axis(last["response"])
        reach = indices["mu_star"] + indices["mu_star_conf"].fillna(0.0)
        chosen |= reach >= indices["response"].map(floor).fillna(np.inf)
    chosen &= indices["mu_star"] > 0
    return list(dict.fromkeys(indices[chosen].sort_values("rank", kind="stable")["parameter"]))


def screen_rule(top: int, ties: bool = False) -> str:
    """How :func:`kept_parameters` chose, in words (the reduced config's header, the CLI)."""
    return f"the top {top} by mu* of each response" + (" and those tied with it" if ties else "")


def _relative(path: Path, start: Path) -> str:
    return Path(os.path.relpath(path.resolve(), start.resolve())).as_posix()


def screened_config(config: Config, indices: pd.DataFrame, top: int, out_path: Path,
                    indices_path: Path | None = None, ties: bool = False) -> dict[str, Any]:
    """A reduced config that keeps the influential inputs and fixes the others (seed §3.4.8).

    The config ``extends:`` the original; every analysed parameter outside the
    union of each response's top ``top`` (by mu*; an input with mu* = 0, which
    changes nothing, is never kept) is written again with
    ``{type: constant, value: <its distribution's nominal>}``, the same mode and
    targets (so the value means the same thing) and a ``provenance`` saying why
    it was fixed. Kept parameters are inherited unchanged. Its run directory is
    ``<original run_dir>_screened``.

    Parameters
    ----------
    config : Config
        The screened config (the one :func:`morris_indices` analysed).
    indices : DataFrame
        From :func:`morris_indices`.
    top : int
        Inputs kept per response.
    out_path : Path
        Where the reduced config will be written (relative paths are relative to it).
    indices_path : Path, optional
        The ``sensitivity.csv`` the decision came from, named in the provenance.
    ties : bool
        Also keep the inputs tied with each response's ``top``-th (:func:`kept_parameters`).
    """
    if config.source is None:
        raise BpsflowError("screening needs a config read from a file (for 'extends:')")
    kept = set(kept_parameters(indices, top, ties))
    analysed = list(dict.fromkeys(indices["parameter"]))
    out_dir = Path(out_path).resolve().parent
    responses = indices["response"].nunique()
    fixed = []
    for name in analysed:
        if name in kept:
            continue
        parameter = config.parameter(name)
        rows = indices[indices["parameter"] == name]
        best = rows.loc[rows["rank"].idxmin()]
        largest = rows.loc[rows["mu_star"].idxmax()]
        entry = parameter.model_dump(mode="json", exclude_none=True,
                                     exclude={"distribution", "provenance"})
        entry["distribution"] = {"type": "constant",
                                 "value": float(parameter.distribution.nominal)}
        entry["provenance"] = {
            "method": "Morris screening (bpsflow sensitivity, seed §3.4.8)",
            "reason": f"not among the top {top} inputs by mu* of any of the {responses} "
                      + ("responses, nor tied with the last of them (mu* confidence "
                         "intervals apart)" if ties else "responses")
                      + "; fixed at its distribution's nominal (median)",
            "best_rank": int(best["rank"]), "best_rank_response": str(best["response"]),
            "max_mu_star": float(largest["mu_star"]),
            "max_mu_star_response": str(largest["response"]),
            "original_distribution": parameter.distribution.model_dump(mode="json",
                                                                       exclude_none=True),
            **({"sensitivity": _relative(indices_path, out_dir)} if indices_path else {}),
            **({"previous": parameter.provenance} if parameter.provenance else {}),
        }
        fixed.append(entry)
    run_dir = Path(str(config.run_dir.resolve()) + "_screened")
    # an empty list is refused in a config that extends another: it would remove nothing
    return {"extends": _relative(config.source, out_dir),
            **({"parameters": fixed} if fixed else {}),
            "execution": {"run_dir": _relative(run_dir, out_dir)}}


def default_screen_path(config: Config) -> Path:
    """``<config stem>_screened.yaml`` beside the config."""
    if config.source is None:
        raise BpsflowError("screening needs a config read from a file (for 'extends:')")
    return config.source.with_name(f"{config.source.stem}_screened.yaml")


#: The first line of a reduced config :func:`write_screened_config` writes (and may replace).
SCREENED_HEADER = "# Morris screening of "


def check_screen_target(config: Config, out_path: Path | None) -> Path:
    """Where ``--screen`` writes, refused before any run if it would overwrite a user's file.

    The config, every base it extends and any existing file that is not an
    earlier reduced config (its first line :data:`SCREENED_HEADER`) are
    refused; so is a path bpsflow cannot write.
    """
    from bpsflow.config import refuse_config_chain
    from bpsflow.files import check_writable_file, refuse_foreign_file

    out_path = Path(out_path or default_screen_path(config))
    refuse_config_chain(config, out_path, "--screen-out")
    refuse_foreign_file(out_path, SCREENED_HEADER, "--screen-out", "a reduced config")
    return check_writable_file(out_path, "--screen-out")


def write_screened_config(config: Config, indices: pd.DataFrame, top: int,
                          out_path: Path | None = None, indices_path: Path | None = None,
                          ties: bool = False) -> tuple[Path, list[str], list[str]]:
    """Write :func:`screened_config` as YAML; check that it loads.

    Returns
    -------
    (path, kept, fixed)
        The written file and the names of the kept and the fixed parameters.
    """
    from bpsflow.config import load_config

    out_path = check_screen_target(config, out_path)
    raw = screened_config(config, indices, top, out_path, indices_path, ties)
    fixed_names = [p["name"] for p in raw.get("parameters", [])]
    kept = [n for n in dict.fromkeys(indices["parameter"]) if n not in fixed_names]
    out_path.parent.mkdir(parents=True, exist_ok=True)
    header = (f"{SCREENED_HEADER}{config.source.name}: {len(kept)} input(s) kept "
              f"({screen_rule(top, ties)}),\n# {len(fixed_names)} fixed at their "
              f"nominal value (see each one's provenance). Written by bpsflow sensitivity.\n")
    write_text_atomic(out_path, header + yaml.safe_dump(raw, sort_keys=False, allow_unicode=True))
    load_config(out_path)  # a reduced config that does not load must not go unnoticed
    return out_path, kept, fixed_names
