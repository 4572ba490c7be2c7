"""Outcomes of a test week from hourly series (seed §4.4.2): totals, means, discomfort.

A series is a matrix of shape (k, n): k realisations (posterior draws with
permuted errors) of the week's n hour-ending values. ``hour_starts`` gives
each column's starting hour, so the outcome can count only some hours
(heating hours: weekdays 06:00-19:00).
"""

from __future__ import annotations

import numpy as np

from bpsflow.decision.intervention import Outcome, counted_hours

__all__ = ["counted_hours", "outcome_values"]


def outcome_values(outcome: Outcome, series: np.ndarray, mask: np.ndarray,
                   setpoint_c: float | np.ndarray | None = None) -> np.ndarray:
    """The outcome of each realisation.

    Parameters
    ----------
    outcome : Outcome
        What to compute (``total``, ``mean`` or ``discomfort``).
    series : ndarray, shape (k, n) or (n,)
        Hourly values in the output's unit.
    mask : ndarray of bool, shape (n,)
        The counted hours (:func:`counted_hours`).
    setpoint_c : float or ndarray of shape (k,), optional
        Comfort setpoint for ``discomfort`` (°C), per realisation or shared.

    Returns
    -------
    ndarray, shape (k,)
        ``total``: sum over the counted hours; ``mean``: their mean;
        ``discomfort``: mean over the counted hours of max(0, setpoint - value),
        degree-hours per counted hour (°C·h/h).
    """
    values = np.atleast_2d(np.asarray(series, dtype=float))[:, mask]
    if values.shape[1] == 0:
        raise ValueError(f"outcome {outcome.name}: no hour of the week is counted")
    if outcome.statistic == "total":
        return values.sum(axis=1)
    if outcome.statistic == "mean":
        return values.mean(axis=1)
    setpoint = np.asarray(setpoint_c, dtype=float).reshape(-1, 1)
    return np.clip(setpoint - values, 0.0, None).mean(axis=1)
