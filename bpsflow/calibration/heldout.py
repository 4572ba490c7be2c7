"""Held-out accuracy of calibrated predictions (seed §4.3.5, Figures 4.7 and 4.9).

The last days of the measured period are never used to calibrate. On them
the same metrics score every prediction: the prior ensemble (the design
runs), the KOH posterior predictive (emulator + discrepancy + noise), the
physical model re-run on posterior draws, and the deterministic optimum
re-run on the physical model.

Per output: CV(RMSE) and NMBE of the prediction's mean (seed eq. 1–2),
nMCRPS of the ensemble (eq. 5–7; for one run it is the nMAE), and the ASHRAE
Guideline 14 check. Temperatures get the un-normalised forms (RMSE, MBE,
MCRPS in °C) and no Guideline 14 verdict (DESIGN.md §5). Guideline 14 has
monthly and hourly criteria only; daily and hourly rows are checked against
the hourly ones (NMBE ±10 %, CV(RMSE) 30 %).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bpsflow.metrics import cv_rmse, guideline14_check, mbe, mcrps, nmbe, nmcrps, rmse

TEMPERATURE_UNITS = ("C", "°C", "DEGC", "K")


def is_temperature(unit: str) -> bool:
    return unit.strip().upper() in TEMPERATURE_UNITS


def score(model: str, resolution: str, outputs: np.ndarray, observed: np.ndarray,
          ensemble: np.ndarray, units: dict[str, str]) -> list[dict]:
    """Held-out metrics of one prediction, one record per output.

    Parameters
    ----------
    model : str
        Label of the prediction (``prior``, ``bayes_gp``, ``bayes_physical``,
        ``deterministic_physical``).
    resolution : str
        ``daily`` or ``hourly``.
    outputs : ndarray, shape (n,)
        Output of each held-out row.
    observed : ndarray, shape (n,)
        Measured values, output units.
    ensemble : ndarray, shape (n, m)
        The prediction's members (m = 1 for a point prediction), output units.
    units : dict
        Output name -> unit.
    """
    ensemble = np.asarray(ensemble, dtype=float).reshape(len(observed), -1)
    records = []
    for output in pd.unique(outputs):
        mine = outputs == output
        y, members = observed[mine], ensemble[mine]
        point = members.mean(axis=1)
        temperature = is_temperature(units.get(output, ""))
        record = {"model": model, "output": output, "resolution": resolution,
                  "unit": units.get(output, ""), "n": int(mine.sum()),
                  "members": int(members.shape[1]),
                  "mcrps": float(mcrps(y, members).value)}
        if len(y) < 2:
            # one held-out value (a single held-out day, daily): the (n − 1) metrics of
            # eq. 1-2 are undefined, and a table of them would be a number with no meaning
            record.update(rmse=None, mbe=None, cv_rmse=None, nmbe=None, guideline14=None,
                          nmcrps=None if temperature else _finite(nmcrps(y, members)))
            records.append(record)
            continue
        record.update(rmse=rmse(y, point), mbe=mbe(y, point))
        if temperature:
            record.update(cv_rmse=None, nmbe=None, nmcrps=None, guideline14=None)
        else:
            bias, spread = nmbe(y, point), cv_rmse(y, point)
            check = guideline14_check(bias, spread, "hourly")
            record.update(cv_rmse=_finite(spread), nmbe=_finite(bias),
                          nmcrps=_finite(nmcrps(y, members)),
                          guideline14="pass" if check.passed else "fail")
        records.append(record)
    return records


def _finite(result) -> float | None:
    value = float(result)
    return value if np.isfinite(value) else None


def table(records: list[dict]) -> pd.DataFrame:
    """Records as a table, one row per model, output and resolution."""
    columns = ["model", "output", "resolution", "unit", "n", "members", "cv_rmse", "nmbe",
               "nmcrps", "rmse", "mbe", "mcrps", "guideline14"]
    return pd.DataFrame(records, columns=columns)
