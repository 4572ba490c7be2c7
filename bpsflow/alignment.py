"""Aligning an ensemble with measured data over each test's evaluation window.

Conventions, stated once: simulation results carry hour-ending timestamps
(EnergyPlus's hourly value at 01:00 is the mean over 00:00–01:00), and so must
the measured file (``bpsflow synth`` writes them that way). A test is
evaluated on its days after the warm-up days; every hour of that window must
be measured — a missing hour, a missing column or a window outside the
measured range is an error that names the file, the column and the hours.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, Test, test_dates
from bpsflow.errors import BpsflowError


@dataclass(frozen=True)
class Aligned:
    """One test and output: observations and the ensemble on the same hours."""

    test: str
    output: str
    timestamps: pd.DatetimeIndex
    observed: np.ndarray          # (n_hours,)
    ensemble: np.ndarray          # (n_hours, n_instances)
    instances: np.ndarray         # (n_instances,)


def evaluation_hours(test: Test, year: int) -> pd.DatetimeIndex:
    """Hour-ending timestamps of a test's evaluated days (after the warm-up)."""
    _, evaluated, last = test_dates(test, year)
    return pd.date_range(pd.Timestamp(evaluated) + pd.Timedelta(hours=1),
                         pd.Timestamp(last) + pd.Timedelta(days=1), freq="h")


def output_evaluation_hours(config: Config, output: str) -> pd.DatetimeIndex:
    """Hour-ending timestamps evaluated for ``output``: every reporting test's, each once."""
    hours = [evaluation_hours(test, config.model.year) for test in config.model.tests
             if output in test.outputs]
    return hours[0].append(hours[1:]).unique() if hours else pd.DatetimeIndex([])


def align(config: Config, results: pd.DataFrame, measured: pd.DataFrame, test: Test,
          output: str, measured_source: Path | str | None = None) -> Aligned:
    """Observations and ensemble members of ``output`` over ``test``'s evaluated hours.

    Raises
    ------
    BpsflowError
        When the measured data lack the column, hours of the window or hold
        NaN there, or when the ensemble lacks hours of the window.
    """
    hours = evaluation_hours(test, config.model.year)
    if output not in measured.columns:
        raise BpsflowError(f"measured data have no column '{output}' (test {test.name}); "
                           f"columns: {list(measured.columns)}", source=measured_source)
    if not measured.index.is_unique:
        dupes = measured.index[measured.index.duplicated()][:3]
        raise BpsflowError(f"measured timestamps repeat (e.g. {list(map(str, dupes))})",
                           source=measured_source)
    if hours[0] < measured.index.min() or hours[-1] > measured.index.max():
        # data that stop exactly one hour short, on the hour, are hour-beginning stamps
        shifted = (measured.index.max() == hours[-1] - pd.Timedelta(hours=1)
                   and measured.index.max().minute == 0)
        raise BpsflowError(
            f"test {test.name} is evaluated over {hours[0]} .. {hours[-1]} (hour-ending) but "
            f"the measured data cover {measured.index.min()} .. {measured.index.max()}"
            + ("; the stamps look hour-beginning (the last hour stamped 23:00): bpsflow reads "
               "hour-ending stamps, 01:00 for the mean over 00:00-01:00, so add one hour to "
               "them" if shifted else ""),
            source=measured_source)
    observed = measured[output].reindex(hours)
    missing = observed.index[observed.isna()]
    if len(missing):
        raise BpsflowError(
            f"column '{output}' lacks {len(missing)} of the {len(hours)} evaluated hours of test "
            f"{test.name} (first: {', '.join(map(str, missing[:3]))}); expected one hour-ending "
            f"value per hour", source=measured_source)
    rows = results[(results["test"] == test.name) & (results["output"] == output)]
    wide = rows.pivot(index="timestamp", columns="instance", values="value").reindex(hours)
    if wide.shape[1] == 0 or wide.isna().all(axis=1).any():
        raise BpsflowError(f"the ensemble has no values of '{output}' for some evaluated hours "
                           f"of test {test.name}: was the run finished with this config?")
    wide = wide.loc[:, wide.notna().all(axis=0)]
    return Aligned(test=test.name, output=output, timestamps=hours,
                   observed=observed.to_numpy(dtype=float), ensemble=wide.to_numpy(dtype=float),
                   instances=wide.columns.to_numpy())


def check_coverage(config: Config, measured: pd.DataFrame,
                   measured_source: Path | str | None = None,
                   outputs: list[str] | None = None) -> None:
    """Raise :func:`align`'s error now if ``measured`` lacks a column or hour a test needs.

    Checked before anything runs, with the same messages as after the run.
    ``outputs`` limits the check to those outputs (default: every test's).
    """
    for test in config.model.tests:
        hours = evaluation_hours(test, config.model.year)
        for output in test.outputs:
            if outputs is not None and output not in outputs:
                continue
            placeholder = pd.DataFrame({"instance": 0, "test": test.name, "output": output,
                                        "timestamp": hours, "value": 0.0})
            align(config, placeholder, measured, test, output, measured_source)
