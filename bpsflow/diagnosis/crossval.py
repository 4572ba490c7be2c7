"""Blocked cross-validation of a model change: folds of whole weeks, out-of-fold errors.

An extension is accepted on data it was not fitted to. A single held-out
block (the last week) has little power for effects that live on few of its
hours (a weekend-only gain has 48 of 168) and none for an effect absent from
it; leave-one-block-out over the whole period holds out every hour once, so
every day type is held out in every fold (seed §4.3.1 on judging a model on
data it did not see; the blocked design follows Roberts et al., 2017,
Ecography 40: 913–929, for autocorrelated data).

The folds are consecutive blocks of whole days, ``days_per_fold`` long (a
week: every fold holds one of each weekday); the held-out block of the
diagnosis (its last days) is the last fold, so the fit on the calibration
hours *is* that fold's fit and its out-of-fold errors are the held-out ones.
A remainder shorter than half a fold joins the block before it.

The errors of the two models are compared over all out-of-fold hours in
time order by a forecast-encompassing test (does the change of prediction
explain the errors before it?) with a Newey–West variance and the fixed-b
reference (:func:`bpsflow.diagnosis.comparison.encompassing_test`), which
decides; the Diebold–Mariano test of the mean loss
(:func:`bpsflow.diagnosis.comparison.loss_difference_test`) is reported.
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def day_blocks(timestamps: pd.DatetimeIndex, heldout: np.ndarray,
               days_per_fold: int = 7) -> np.ndarray:
    """Fold number of every hour: consecutive blocks of whole days, the held-out block last.

    Parameters
    ----------
    timestamps : DatetimeIndex
        Hour-ending stamps of the data, in time order.
    heldout : ndarray of bool
        The diagnosis' held-out hours (its last days); they form the last fold.
    days_per_fold : int
        Length of a fold in days (7: every fold holds each day of the week once).

    Returns
    -------
    ndarray of int
        ``0 … F − 1`` per hour; ``F − 1`` marks the held-out block.
    """
    if days_per_fold < 1:
        raise ValueError(f"days_per_fold must be at least 1, got {days_per_fold}")
    heldout = np.asarray(heldout, dtype=bool)
    days = np.asarray((pd.DatetimeIndex(timestamps) - pd.Timedelta(hours=1)).normalize())
    calibration_days = np.unique(days[~heldout])
    count = max(int(round(len(calibration_days) / days_per_fold)), 1)
    # equal blocks of whole days; a remainder spreads over them (never a stub fold)
    edges = np.array_split(calibration_days, count)
    fold_of_day = {day: number for number, block in enumerate(edges) for day in block}
    folds = np.array([fold_of_day.get(day, count) for day in days], dtype=int)
    folds[heldout] = count
    return folds


def out_of_fold(folds: np.ndarray, predictions: dict[int, np.ndarray]) -> np.ndarray:
    """Every hour's prediction by the fit that did not see its fold.

    Parameters
    ----------
    folds : ndarray of int
        Fold number per hour (:func:`day_blocks`).
    predictions : dict
        Fold number -> prediction at every hour by the fit without that fold.
    """
    folds = np.asarray(folds)
    missing = sorted(set(np.unique(folds)) - set(predictions))
    if missing:
        raise ValueError(f"no prediction for fold(s) {missing}")
    combined = np.full(len(folds), np.nan)
    for number, prediction in predictions.items():
        mask = folds == number
        combined[mask] = np.asarray(prediction, dtype=float)[mask]
    return combined


def bic_weight(bic_best: float, bic_other: float) -> float:
    """Posterior probability of the better of two models from their BIC (Schwarz, 1978).

    With equal prior odds, ``P(best | data) ≈ 1 / (1 + exp(−ΔBIC/2))`` for
    ``ΔBIC = bic_other − bic_best`` (Kass & Raftery, 1995, J. Am. Stat.
    Assoc. 90: 773–795: ΔBIC < 2 is "not worth more than a bare mention",
    2–6 positive, 6–10 strong, > 10 very strong evidence).
    """
    delta = float(bic_other) - float(bic_best)
    if not np.isfinite(delta):
        return 1.0 if delta > 0 else 0.5
    from scipy.special import expit

    return float(expit(delta / 2.0))


def evidence_words(delta_bic: float) -> str:
    """Kass & Raftery's (1995) words for a BIC difference between two causes."""
    if delta_bic < 2:
        return "nearly indistinguishable"
    if delta_bic < 6:
        return "positive"
    if delta_bic < 10:
        return "strong"
    return "very strong"
