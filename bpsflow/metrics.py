"""Accuracy metrics for point and ensemble predictions (seed §2.4, eq. 1–2, 5–7).

Point metrics compare observations ``y`` with one prediction ``ŷ``:
NMBE (eq. 1) and CV(RMSE) (eq. 2), with ``p`` lost degrees of freedom, and the
normalised mean absolute error nMAE. Their un-normalised forms (MBE, RMSE,
MAE) are in the unit of the data and are the ones to use for temperatures (°C).

Ensemble metrics score an ensemble ``x_1..x_m`` per observation with the
continuous ranked probability score (CRPS, eq. 5), averaged over observations
(MCRPS, eq. 6) and optionally normalised by the observation mean (nMCRPS,
eq. 7). Two estimators of the CRPS of an ensemble are offered:

``"standard"``
    The CRPS of the ensemble's empirical distribution,
    ``E|X−y| − ½ E|X−X′|`` with the spread term averaged over all ``m²``
    ordered pairs (including a member with itself).
``"fair"``
    The spread term averaged over the ``m(m−1)`` pairs of distinct members,
    which makes the score an unbiased estimate of the CRPS of the distribution
    the members were drawn from.

Both are computed exactly in O(m log m) per observation by sorting.

Normalised results
------------------
Every normalised metric (NMBE, CV(RMSE), nMAE, nMCRPS) and every ensemble
aggregate (MCRPS) returns a :class:`MetricResult`: the value, the normaliser
ȳ it was divided by, the CRPS estimator when one was used, and a note.
When ȳ is too close to zero for the ratio to mean anything (a heating test
that barely heats), the value is NaN and the note says why — never ``inf``.
``float(result)`` gives the value.

Validation thresholds and risks (seed §3.6.2, DESIGN §6)
---------------------------------------------------------
:func:`instance_nmae` treats every ensemble member as a point prediction;
:func:`validation_threshold` takes a quantile of those metric values (type I
risk ``1 − q``); :func:`type_ii_risk` is the share of invalid predictions the
threshold would accept; :func:`reduced_risk` is ``q`` minus that share.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Estimator = Literal["standard", "fair"]
ESTIMATORS: tuple[str, ...] = ("standard", "fair")

#: A mean whose magnitude is at most this fraction of the data's largest
#: magnitude is treated as zero when normalising.
NEAR_ZERO_MEAN_RTOL = 1e-3

# Rows of an ensemble handled at a time by :func:`crps_ensemble`: bounds the
# temporaries (two float64 copies of a block) and keeps them in cache; with
# 200 members a block is ~1.6 MB, and blocks of 4096 rows or more measured
# about 3x slower (bench/metrics_bench.py).
_ROWS_PER_BLOCK = 1024


# ---------------------------------------------------------------------------
# Result type and normalisation


@dataclass(frozen=True, eq=False)
class MetricResult:
    """A metric value with what it was normalised by and how it was estimated.

    Attributes
    ----------
    name : str
        The metric, e.g. ``"NMBE"``, ``"CV(RMSE)"``, ``"nMAE"``, ``"MCRPS"``,
        ``"nMCRPS"``.
    value : float or numpy.ndarray
        The metric: a fraction (not a percentage) for normalised metrics, the
        data's unit for MCRPS. An array of shape ``(m,)`` for per-instance
        metrics (:func:`instance_nmae`). NaN when undefined; ``note`` says why.
    normaliser : float or None
        The observation mean ȳ the value was divided by, in the data's unit;
        None for un-normalised metrics.
    estimator : str or None
        The CRPS estimator (``"standard"`` or ``"fair"``) for ensemble
        metrics; None for point metrics.
    note : str
        Empty when the value is an ordinary number; otherwise the reason it is
        NaN (near-zero mean, missing values).
    """

    name: str
    value: float | np.ndarray
    normaliser: float | None = None
    estimator: str | None = None
    note: str = ""

    def __float__(self) -> float:
        return float(self.value)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return np.asarray(self.value, dtype=dtype)

    def __str__(self) -> str:
        text = f"{self.name} = {np.array2string(np.asarray(self.value), precision=6)}"
        if self.estimator:
            text += f" ({self.estimator} estimator)"
        if self.note:
            text += f" [{self.note}]"
        return text


def normalised(value, mean: float, scale: float, *, name: str,
               estimator: str | None = None,
               rtol: float = NEAR_ZERO_MEAN_RTOL) -> MetricResult:
    """Divide a metric by the observation mean, or say why it cannot be.

    Parameters
    ----------
    value : float or array_like
        The un-normalised metric, in the data's unit.
    mean : float
        The observation mean ȳ, in the data's unit.
    scale : float
        The data's magnitude (largest absolute observed or predicted value),
        in the data's unit; ȳ is compared with it.
    name : str
        The metric's name, recorded in the result.
    estimator : str, optional
        The CRPS estimator behind ``value``, recorded in the result.
    rtol : float, default :data:`NEAR_ZERO_MEAN_RTOL`
        ȳ is treated as zero when ``|ȳ| <= rtol * scale``.

    Returns
    -------
    MetricResult
        ``value / mean``; NaN with a note when ȳ or the value is NaN or ȳ is
        near zero.
    """
    value = np.asarray(value, dtype=float)
    nan = np.full_like(value, np.nan)
    nan = nan if nan.ndim else float("nan")

    def result(v, note: str = "") -> MetricResult:
        return MetricResult(name, v if np.ndim(v) else float(v), float(mean), estimator, note)

    if not np.isfinite(mean) or not np.isfinite(scale):
        return result(nan, "missing or non-finite values in the inputs")
    if abs(mean) <= rtol * scale:
        return result(nan, f"observation mean {mean:.3g} is near zero (|mean| <= {rtol:g} x "
                           f"data scale {scale:.3g}); use the un-normalised metric")
    if np.isnan(value).any():
        return result(value / mean, "missing values in the inputs")
    return result(value / mean)


# ---------------------------------------------------------------------------
# Point metrics (eq. 1–2)


def _pair(observed, predicted) -> tuple[np.ndarray, np.ndarray]:
    y = np.asarray(observed, dtype=float).ravel()
    y_hat = np.asarray(predicted, dtype=float).ravel()
    if y.shape != y_hat.shape:
        raise ValueError(f"observed has {y.size} values but predicted has {y_hat.size}")
    if y.size == 0:
        raise ValueError("no observations")
    return y, y_hat


def _degrees_of_freedom(n: int, p: int) -> int:
    if not n - p > 0:
        raise ValueError(f"n - p must be positive: {n} observations, p = {p}")
    return n - p


def _scale(*arrays: np.ndarray) -> float:
    finite = [np.abs(a[np.isfinite(a)]) for a in arrays]
    return max((float(a.max()) for a in finite if a.size), default=0.0)


def mbe(observed, predicted, p: int = 1) -> float:
    """Mean bias error ``Σ(y − ŷ) / (n − p)``, in the data's unit (e.g. °C).

    The numerator of NMBE (seed eq. 1): positive when the prediction is low.

    Parameters
    ----------
    observed, predicted : array_like
        Observations ``y`` and point predictions ``ŷ`` of the same length
        ``n``, in the same unit. A NaN in either gives NaN.
    p : int, default 1
        Lost degrees of freedom.

    Returns
    -------
    float
        Mean bias error, in the data's unit.
    """
    y, y_hat = _pair(observed, predicted)
    return float(np.sum(y - y_hat) / _degrees_of_freedom(y.size, p))


def rmse(observed, predicted, p: int = 1) -> float:
    """Root-mean-square error ``sqrt(Σ(y − ŷ)² / (n − p))``, in the data's unit.

    The numerator of CV(RMSE) (seed eq. 2). Parameters as :func:`mbe`.

    Returns
    -------
    float
        Root-mean-square error, in the data's unit (e.g. °C).
    """
    y, y_hat = _pair(observed, predicted)
    return float(np.sqrt(np.sum((y - y_hat) ** 2) / _degrees_of_freedom(y.size, p)))


def error_concentration(observed, predicted, top_share: float = 0.01) -> tuple[np.ndarray, float]:
    """The few largest errors and their share of the squared error behind an RMSE.

    An hourly CV(RMSE) can rest on a handful of hours (a reheat peak that a
    simulation's time step moves by one step); the share says how far the
    metric describes the whole record.

    Parameters
    ----------
    observed, predicted : array_like
        Observations and point predictions of the same length; pairs with a
        NaN are left out.
    top_share : float
        Share of the (finite) pairs counted as "the few", at least one pair (-).

    Returns
    -------
    positions : ndarray of int
        Positions (in the given arrays) of the largest absolute errors, largest first.
    share : float
        Their share of the sum of squared errors (-); 0 when every error is 0.
    """
    y = np.asarray(observed, dtype=float).ravel()
    y_hat = np.asarray(predicted, dtype=float).ravel()
    if y.shape != y_hat.shape:
        raise ValueError(f"observed and predicted differ in length ({y.size} and {y_hat.size})")
    squared = (y - y_hat) ** 2
    finite = np.flatnonzero(np.isfinite(squared))
    if finite.size == 0:
        return np.array([], dtype=int), 0.0
    count = max(1, int(round(top_share * finite.size)))
    order = finite[np.argsort(-squared[finite], kind="stable")][:count]
    total = float(np.sum(squared[finite]))
    return order, (float(np.sum(squared[order]) / total) if total > 0 else 0.0)


def mae(observed, predicted) -> float:
    """Mean absolute error ``Σ|y − ŷ| / n``, in the data's unit (e.g. °C).

    Equal to the MCRPS (seed eq. 6) of a one-member ensemble.

    Parameters
    ----------
    observed, predicted : array_like
        Observations and point predictions of the same length. A NaN in
        either gives NaN.

    Returns
    -------
    float
        Mean absolute error, in the data's unit.
    """
    y, y_hat = _pair(observed, predicted)
    return float(np.mean(np.abs(y - y_hat)))


def nmbe(observed, predicted, p: int = 1, *, rtol: float = NEAR_ZERO_MEAN_RTOL) -> MetricResult:
    """Normalised mean bias error (seed eq. 1): ``Σ(y − ŷ) / ((n − p) · ȳ)``.

    Parameters
    ----------
    observed, predicted : array_like
        Observations ``y`` and point predictions ``ŷ`` of the same length
        ``n``, in the same unit (e.g. W or kWh). A NaN in either gives NaN.
    p : int, default 1
        Lost degrees of freedom (1 in BPS calibration, seed §1.1.2.2).
    rtol : float, default :data:`NEAR_ZERO_MEAN_RTOL`
        ȳ counts as zero when ``|ȳ|`` is at most ``rtol`` times the largest
        absolute observed or predicted value; the result is then NaN.

    Returns
    -------
    MetricResult
        ``name="NMBE"``, value as a fraction (0.05 = 5 %), positive when the
        prediction is low on average.
    """
    y, y_hat = _pair(observed, predicted)
    return normalised(mbe(y, y_hat, p), float(np.mean(y)), _scale(y, y_hat),
                      name="NMBE", rtol=rtol)


def cv_rmse(observed, predicted, p: int = 1, *,
            rtol: float = NEAR_ZERO_MEAN_RTOL) -> MetricResult:
    """Coefficient of variation of the RMSE (seed eq. 2): ``sqrt(Σ(y − ŷ)² / (n − p)) / ȳ``.

    Parameters and near-zero handling as :func:`nmbe`.

    Returns
    -------
    MetricResult
        ``name="CV(RMSE)"``, value as a fraction (0.15 = 15 %).
    """
    y, y_hat = _pair(observed, predicted)
    return normalised(rmse(y, y_hat, p), float(np.mean(y)), _scale(y, y_hat),
                      name="CV(RMSE)", rtol=rtol)


def nmae(observed, predicted, *, rtol: float = NEAR_ZERO_MEAN_RTOL) -> MetricResult:
    """Normalised mean absolute error ``Σ|y − ŷ| / (n · ȳ)``.

    The nMCRPS (seed eq. 7) of a point prediction (seed §3.6.2). Parameters
    and near-zero handling as :func:`nmbe` (no ``p``).

    Returns
    -------
    MetricResult
        ``name="nMAE"``, value as a fraction.
    """
    y, y_hat = _pair(observed, predicted)
    return normalised(mae(y, y_hat), float(np.mean(y)), _scale(y, y_hat),
                      name="nMAE", rtol=rtol)


# ---------------------------------------------------------------------------
# CRPS (eq. 5–7)


def _check_estimator(estimator: str) -> None:
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")


def _ensemble_pair(observations, ensemble) -> tuple[np.ndarray, np.ndarray]:
    y = np.asarray(observations, dtype=float)
    x = np.asarray(ensemble, dtype=float)
    if y.ndim != 1 or x.ndim != 2 or x.shape[0] != y.shape[0]:
        raise ValueError(f"expected observations of shape (n,) and ensemble of shape (n, m); "
                         f"got {y.shape} and {x.shape} (pass a point prediction as "
                         f"predicted[:, None])")
    if x.shape[1] == 0:
        raise ValueError("the ensemble has no members (m = 0)")
    return y, x


def _crps_complete_rows(y: np.ndarray, x: np.ndarray, estimator: str) -> np.ndarray:
    """CRPS of rows with no missing member: one rank-weight vector for all rows."""
    m = x.shape[1]
    ordered = np.sort(x, axis=1)
    # Σ_i (2i − m − 1) x_(i) = ½ Σ_i Σ_j |x_i − x_j|  (i = 1..m, sorted ascending).
    rank_weights = 2.0 * np.arange(1, m + 1) - m - 1
    half_pair_sum = ordered @ rank_weights
    np.subtract(ordered, y[:, None], out=ordered)
    np.abs(ordered, out=ordered)
    mean_abs_error = ordered.mean(axis=1)
    pairs = m * m if estimator == "standard" else m * (m - 1)
    if pairs == 0:  # fair estimator, one member: no pair, no spread term
        return mean_abs_error
    # ½ E|X − X′| = ½ · (2 · half_pair_sum) / pairs
    return mean_abs_error - half_pair_sum / pairs


def _crps_rows_with_gaps(y: np.ndarray, x: np.ndarray, estimator: str) -> np.ndarray:
    """CRPS of rows with missing members: each row scored on its own members."""
    ordered = np.sort(x, axis=1)  # NaN sorts last
    valid = ~np.isnan(ordered)
    members = valid.sum(axis=1)
    rank = np.arange(1, x.shape[1] + 1)
    rank_weights = np.where(valid, 2.0 * rank - members[:, None] - 1, 0.0)
    filled = np.where(valid, ordered, 0.0)
    half_pair_sum = np.einsum("ij,ij->i", filled, rank_weights)
    abs_error_sum = np.where(valid, np.abs(ordered - y[:, None]), 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_abs_error = abs_error_sum / members
        pairs = members * members if estimator == "standard" else members * (members - 1)
        spread = np.where(pairs > 0, half_pair_sum / np.maximum(pairs, 1), 0.0)
    return np.where(members > 0, mean_abs_error - spread, np.nan)


def crps_ensemble(observations, ensemble, estimator: Estimator = "standard") -> np.ndarray:
    """CRPS of an ensemble at each observation (seed eq. 5), exact, by sorting.

    ``CRPS = E|X − y| − ½ E|X − X′|`` over the members ``x_1..x_m`` of each
    row. With the members sorted, ``x_(1) <= … <= x_(m)``, the pair sum is
    ``Σ_i Σ_j |x_i − x_j| = 2 Σ_i (2i − m − 1) x_(i)``, so each row costs
    O(m log m) instead of O(m²).

    Parameters
    ----------
    observations : array_like, shape (n,)
        Observed values ``y``, in the data's unit.
    ensemble : array_like, shape (n, m)
        Ensemble members for each observation, same unit. For a point
        prediction pass ``predicted[:, None]`` (m = 1).
    estimator : {"standard", "fair"}, default "standard"
        ``"standard"``: the spread term ``E|X − X′|`` averages over all
        ``m²`` ordered pairs, i.e. the CRPS of the ensemble's empirical
        distribution. ``"fair"``: it averages over the ``m(m − 1)`` pairs of
        distinct members (unbiased for the distribution the members were drawn
        from). With one member the fair spread term is taken as zero, so both
        estimators give ``|x − y|``.

    Returns
    -------
    numpy.ndarray, shape (n,)
        CRPS per observation, in the data's unit; non-negative for the
        standard estimator (the fair one can be slightly negative).

    Notes
    -----
    Missing values: a NaN observation gives NaN for its row. NaN members are
    dropped from their row, which is then scored as an ensemble of its
    remaining ``m_i`` members; a row with no member left gives NaN. Members
    are expected to be finite otherwise.
    """
    _check_estimator(estimator)
    y, x = _ensemble_pair(observations, ensemble)
    scores = np.empty(y.shape[0])
    for start in range(0, y.shape[0], _ROWS_PER_BLOCK):
        rows = slice(start, start + _ROWS_PER_BLOCK)
        y_block, x_block = y[rows], x[rows]
        gaps = np.isnan(x_block).any(axis=1)
        if gaps.any():
            block = np.empty(y_block.shape[0])
            block[~gaps] = _crps_complete_rows(y_block[~gaps], x_block[~gaps], estimator)
            block[gaps] = _crps_rows_with_gaps(y_block[gaps], x_block[gaps], estimator)
            scores[rows] = block
        else:
            scores[rows] = _crps_complete_rows(y_block, x_block, estimator)
    scores[np.isnan(y)] = np.nan
    return scores


def mcrps(observations, ensemble, estimator: Estimator = "standard") -> MetricResult:
    """Mean CRPS over observations (seed eq. 6), in the data's unit (e.g. °C).

    Parameters
    ----------
    observations : array_like, shape (n,)
        Observed values.
    ensemble : array_like, shape (n, m)
        Ensemble members per observation.
    estimator : {"standard", "fair"}, default "standard"
        CRPS estimator, see :func:`crps_ensemble`; recorded in the result.

    Returns
    -------
    MetricResult
        ``name="MCRPS"``, ``normaliser=None``; NaN with a note if any
        observation is NaN or any row has no member left.
    """
    scores = crps_ensemble(observations, ensemble, estimator)
    value = float(np.mean(scores))
    note = "missing values in the inputs" if np.isnan(value) else ""
    return MetricResult("MCRPS", value, None, estimator, note)


def nmcrps(observations, ensemble, estimator: Estimator = "standard", *,
           rtol: float = NEAR_ZERO_MEAN_RTOL) -> MetricResult:
    """Normalised mean CRPS (seed eq. 7): ``MCRPS / ȳ``.

    For a point prediction (m = 1) it equals :func:`nmae`.

    Parameters
    ----------
    observations, ensemble, estimator
        As :func:`mcrps`.
    rtol : float, default :data:`NEAR_ZERO_MEAN_RTOL`
        ȳ counts as zero when ``|ȳ|`` is at most ``rtol`` times the largest
        absolute observed or member value; the result is then NaN.

    Returns
    -------
    MetricResult
        ``name="nMCRPS"``, value as a fraction, ``normaliser`` = ȳ,
        ``estimator`` recorded.
    """
    y, x = _ensemble_pair(observations, ensemble)
    mean_score = mcrps(y, x, estimator)
    return normalised(mean_score.value, float(np.mean(y)), _scale(y, x.ravel()),
                      name="nMCRPS", estimator=estimator, rtol=rtol)


# ---------------------------------------------------------------------------
# ASHRAE Guideline 14 calibration criteria


@dataclass(frozen=True)
class CalibrationCriteria:
    """Limits a calibrated model must meet on NMBE and CV(RMSE).

    Both limits are inclusive: a model passes when ``|NMBE| <= max_abs_nmbe``
    and ``CV(RMSE) <= max_cv_rmse``. Fractions, not percentages.
    """

    clause: str
    data_interval: str
    max_abs_nmbe: float
    max_cv_rmse: float


#: ASHRAE Guideline 14 calibration criteria for whole-building simulation, monthly data.
GUIDELINE14_MONTHLY = CalibrationCriteria(
    "ASHRAE Guideline 14", "monthly", max_abs_nmbe=0.05, max_cv_rmse=0.15)
#: ASHRAE Guideline 14 calibration criteria for whole-building simulation, hourly data.
GUIDELINE14_HOURLY = CalibrationCriteria(
    "ASHRAE Guideline 14", "hourly", max_abs_nmbe=0.10, max_cv_rmse=0.30)
GUIDELINE14 = {"monthly": GUIDELINE14_MONTHLY, "hourly": GUIDELINE14_HOURLY}


@dataclass(frozen=True)
class CalibrationCheck:
    """Outcome of :func:`guideline14_check`.

    Attributes
    ----------
    passed : bool
        Both criteria met.
    nmbe_passed, cv_rmse_passed : bool
        Each criterion on its own (False when the metric is NaN).
    nmbe, cv_rmse : float
        The values checked, as fractions.
    criteria : CalibrationCriteria
        The thresholds used and the clause they come from.
    """

    passed: bool
    nmbe_passed: bool
    cv_rmse_passed: bool
    nmbe: float
    cv_rmse: float
    criteria: CalibrationCriteria


def guideline14_check(nmbe_value, cv_rmse_value,
                      data_interval: Literal["monthly", "hourly"]) -> CalibrationCheck:
    """Check NMBE and CV(RMSE) against ASHRAE Guideline 14 (seed §1.1.2.2).

    Parameters
    ----------
    nmbe_value : float or MetricResult
        NMBE as a fraction (e.g. from :func:`nmbe`).
    cv_rmse_value : float or MetricResult
        CV(RMSE) as a fraction (e.g. from :func:`cv_rmse`).
    data_interval : {"monthly", "hourly"}
        Interval of the calibration data: monthly ``|NMBE| <= 5 %`` and
        ``CV(RMSE) <= 15 %``; hourly ``<= 10 %`` and ``<= 30 %``. Limits are
        inclusive. A NaN metric fails.

    Returns
    -------
    CalibrationCheck
        Pass/fail per criterion and overall, with the thresholds used.
    """
    if data_interval not in GUIDELINE14:
        raise ValueError(f"data_interval must be one of {tuple(GUIDELINE14)}, "
                         f"got {data_interval!r}")
    criteria = GUIDELINE14[data_interval]
    bias, spread = float(nmbe_value), float(cv_rmse_value)
    nmbe_ok = bool(abs(bias) <= criteria.max_abs_nmbe)
    cv_ok = bool(spread <= criteria.max_cv_rmse)
    return CalibrationCheck(nmbe_ok and cv_ok, nmbe_ok, cv_ok, bias, spread, criteria)


# ---------------------------------------------------------------------------
# Validation thresholds and risks (seed §3.6.2)


def instance_nmae(observations, ensemble, *,
                  rtol: float = NEAR_ZERO_MEAN_RTOL) -> MetricResult:
    """nMAE of every ensemble member taken as a point prediction (seed §3.6.2).

    Parameters
    ----------
    observations : array_like, shape (n,)
        Observed values of one test (e.g. W).
    ensemble : array_like, shape (n, m)
        One column per instance (model run), same unit.
    rtol : float, default :data:`NEAR_ZERO_MEAN_RTOL`
        Near-zero mean tolerance, as :func:`nmbe`.

    Returns
    -------
    MetricResult
        ``name="instance nMAE"``, ``value`` of shape ``(m,)``: for instance
        ``j``, ``Σ_i |y_i − x_ij| / (n · ȳ)``. All NaN, with a note, when ȳ is
        near zero. ``numpy.asarray(result)`` gives the values.
    """
    y, x = _ensemble_pair(observations, ensemble)
    instance_mae = np.mean(np.abs(x - y[:, None]), axis=0)
    return normalised(instance_mae, float(np.mean(y)), _scale(y, x.ravel()),
                      name="instance nMAE", rtol=rtol)


def validation_threshold(metric_values, q: float = 0.9, *, method: str = "linear") -> float:
    """Validation threshold: the ``q``-quantile of valid predictions' metric values.

    A prediction is accepted when its metric is at most the threshold, so a
    valid prediction is rejected with probability about ``1 − q`` (the type I
    risk; seed §3.6.2 uses ``q = 0.9``).

    Parameters
    ----------
    metric_values : array_like or MetricResult
        Metric of each valid prediction, e.g. :func:`instance_nmae` of the
        refined ensemble.
    q : float, default 0.9
        Quantile probability, in [0, 1].
    method : str, default "linear"
        Quantile definition, passed to :func:`numpy.quantile`.

    Returns
    -------
    float
        The threshold, in the metric's unit; NaN if any value is NaN.
    """
    if not 0.0 <= q <= 1.0:
        raise ValueError(f"q must be in [0, 1], got {q}")
    values = np.asarray(metric_values, dtype=float).ravel()
    if values.size == 0:
        raise ValueError("no metric values")
    return float(np.quantile(values, q, method=method))


def type_ii_risk(threshold: float, invalid_metric_values) -> float:
    """Share of invalid predictions the threshold accepts (metric ``<= threshold``).

    Parameters
    ----------
    threshold : float
        From :func:`validation_threshold`.
    invalid_metric_values : array_like or MetricResult
        Metric of each prediction known or assumed to be invalid (seed
        §3.6.2: the baseline ensemble; or deliberately wrong models).

    Returns
    -------
    float
        Type II risk in [0, 1]; NaN if the threshold or any value is NaN.
    """
    values = np.asarray(invalid_metric_values, dtype=float).ravel()
    if values.size == 0:
        raise ValueError("no invalid metric values")
    if np.isnan(threshold) or np.isnan(values).any():
        return float("nan")
    return float(np.mean(values <= threshold))


def reduced_risk(q: float, type_ii: float) -> float:
    """Reduced risk ``q − type II risk`` (seed §3.6.2, Table 3.5).

    Parameters
    ----------
    q : float
        Quantile probability of the threshold (1 − type I risk).
    type_ii : float
        From :func:`type_ii_risk`.

    Returns
    -------
    float
        Reduced risk, a fraction (seed Table 3.5 gives it in %).
    """
    return float(q - type_ii)
