"""Is an extended model really better? Out-of-fold error tests and BIC.

An extension is kept only when what it changes in the prediction of data it
was not fitted to explains the errors of the model without it, by more than
chance (:func:`encompassing_test`, Harvey, Leybourne & Newbold, 1998), and its
extra parameters pay for themselves (:func:`bic`, Schwarz, 1978). Whether it
predicts better on average is reported (:func:`loss_difference_test`, Diebold
& Mariano, 1995). The tests read errors in time order; hourly errors are
autocorrelated, so their variances are Newey–West long-run variances.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from bpsflow.diagnosis.structure import (
    _BARTLETT_C1,
    _BARTLETT_C2,
    autocorrelation,
    default_hac_lags,
)

LOSSES = ("squared", "absolute")
#: Relative bias of the long-run variance tolerated by the default lag length.
#: Tighter than the driver tests' (structure.HAC_BIAS_TOLERANCE): this test
#: decides alone at its nominal level, so its size matters more than its power.
LOSS_DIFFERENCE_BIAS_TOLERANCE = 0.025


def _loss(errors: np.ndarray, loss: str) -> np.ndarray:
    if loss == "squared":
        return errors ** 2
    if loss == "absolute":
        return np.abs(errors)
    raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")


def _paired(errors_before: np.ndarray, errors_after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two models' errors at the hours where both are finite, in time order."""
    before = np.asarray(errors_before, dtype=float).ravel()
    after = np.asarray(errors_after, dtype=float).ravel()
    if before.shape != after.shape:
        raise ValueError(f"errors_before and errors_after differ in length "
                         f"({before.size} and {after.size})")
    keep = np.isfinite(before) & np.isfinite(after)
    return before[keep], after[keep]


def _one_sided_p(statistic: float, lags: int, n: int, reference: str) -> float:
    """Upper-tail p of a Newey–West (Bartlett) t statistic: fixed-b or normal reference.

    Fixed-b: ``t / sqrt(κ) ~ t(K)`` with ``b = (L + 1)/n``, ``κ = exp(b)``,
    ``K = ⌈3/(2b)⌉`` (the q = 1 case of
    :func:`bpsflow.diagnosis.structure.fixed_b_pvalue`).
    """
    if reference == "fixed-b":
        b = (lags + 1) / n
        kappa = math.exp(b * _BARTLETT_C1)
        dof = max(math.ceil(1.0 / (b * _BARTLETT_C2)), 1)
        return float(stats.t.sf(statistic / math.sqrt(kappa), dof))
    if reference == "normal":
        return float(stats.norm.sf(statistic))
    raise ValueError(f"reference must be 'fixed-b' or 'normal', got {reference!r}")


def loss_difference_test(errors_before: np.ndarray, errors_after: np.ndarray, *,
                         loss: str = "squared", lags: int | None = None,
                         reference: str = "fixed-b") -> dict:
    """Diebold–Mariano test that the model after a change predicts better.

    With ``d_t = L(e_before,t) − L(e_after,t)`` the loss differential, the
    statistic is ``DM = d̄ / sqrt(Ω̂ / n)`` with ``Ω̂`` the Newey–West
    (Bartlett) long-run variance of ``d`` (Diebold & Mariano, 1995, J. Bus.
    Econ. Stat. 13: 253–263), times the small-sample factor ``n/(n − 1)``:
    exactly the t-value of OLS of ``d`` on a constant with statsmodels' HAC
    covariance (``use_correction=True``). The null is equal accuracy; the
    p-value is one-sided, small when the model after is better.

    Hourly errors of a building model carry slow, strongly autocorrelated
    components, and so does ``d``. The default lag length is
    :func:`bpsflow.diagnosis.structure.default_hac_lags` of ``d`` with the
    variance's bias held under 2.5 % (84 lags, the cap n/2, for a held-out
    week with lag-1 autocorrelation 0.8), so wide that the reference
    distribution is the fixed-b one (Kiefer & Vogelsang, 2005; for this test
    Coroneo & Iacone, 2020, J. Appl. Econometrics 35: 391–409):
    ``DM / sqrt(κ) ~ t(K)`` with ``b = (L + 1)/n``, ``κ = exp(b)`` and
    ``K = ⌈3/(2b)⌉`` for the Bartlett kernel (the q = 1 case of
    :func:`bpsflow.diagnosis.structure.fixed_b_pvalue`). Measured on AR(1)
    loss differences with mean 0 (2000 series each), the test rejects at the
    5 % level in 5.1 % (n = 168 h, φ = 0.8), 6.6 % (n = 168, φ = 0.9),
    5.5 % (n = 336, φ = 0.8) and 5.9 % (n = 168, φ = 0.5) of them; with the
    normal reference 12–18 %, with the textbook ``4 (n/100)^(2/9)`` lags and
    the normal reference 9–24 %. The price is power: a week of errors that
    autocorrelated holds ~15 independent hours, and only a clear gain passes.
    ``reference="normal"`` gives the original test's N(0, 1) p-value.

    Parameters
    ----------
    errors_before, errors_after : ndarray
        Prediction errors (measured − predicted, output units) of the two
        models at the same held-out hours, in time order. Hours where either
        is missing are dropped.
    loss : {"squared", "absolute"}
        Loss of an error.
    lags : int, optional
        Newey–West lag length; default :func:`default_hac_lags`.
    reference : {"fixed-b", "normal"}
        Reference distribution of the statistic.

    Returns
    -------
    dict
        ``mean_difference`` (mean of ``d``: squared output units for the
        squared loss; > 0 when the model after is better), ``statistic``
        (DM), ``p_value`` (one-sided), ``lags``, ``n``, ``loss``,
        ``reference``.
    """
    before, after = _paired(errors_before, errors_after)
    difference = _loss(before, loss) - _loss(after, loss)
    n = difference.size
    if n < 3:
        raise ValueError(f"the loss-difference test needs at least 3 paired errors, got {n}")
    centred = difference - difference.mean()
    lags = default_hac_lags(centred, tolerance=LOSS_DIFFERENCE_BIAS_TOLERANCE) \
        if lags is None else int(lags)
    lags = min(lags, n - 1)
    # Bartlett-weighted autocovariances: statsmodels' weights 1 − j/(L + 1).
    long_run = centred @ centred / n
    for lag in range(1, lags + 1):
        long_run += 2 * (1 - lag / (lags + 1)) * (centred[lag:] @ centred[:-lag]) / n
    long_run *= n / (n - 1)
    mean_difference = float(difference.mean())
    if long_run <= 0:
        statistic = math.copysign(math.inf, mean_difference) if mean_difference else 0.0
    else:
        statistic = mean_difference / math.sqrt(long_run / n)
    p_value = _one_sided_p(statistic, lags, n, reference)
    return {"mean_difference": mean_difference, "statistic": float(statistic),
            "p_value": p_value, "lags": int(lags), "n": int(n), "loss": loss,
            "reference": reference}


def encompassing_test(errors_before: np.ndarray, errors_after: np.ndarray, *,
                      weight: float = 0.5, lags: int | None = None,
                      reference: str = "fixed-b") -> dict:
    """Forecast-encompassing test: should a combination lean to the model after the change?

    OLS of the errors before on the change of prediction,
    ``e_before,t = α + λ (e_before,t − e_after,t) + u_t``, and a one-sided
    Newey–West t-test of ``λ ≤ weight`` against ``λ > weight`` (Chong &
    Hendry, 1986; Harvey, Leybourne & Newbold, 1998, J. Bus. Econ. Stat. 16:
    254–259, who test ``weight = 0``). ``λ`` is the weight of the model after
    in the least-squares combination ``(1 − λ) prediction_before + λ
    prediction_after``: 1 when the change removes the errors it touches, near
    0 when it is unrelated to them (a change fitted to other folds' noise).
    With the default ``weight = 1/2`` the alternative is that the combination
    leans to the model after; since the squared loss falls by ``(2λ − 1)
    var(change)`` (apart from the means), that is a test that the model after
    predicts better, as the Diebold–Mariano test of the squared loss
    (:func:`loss_difference_test`) is. It has more power for an effect acting
    a few hours a week (a weekday-evening gain: 15 of 168 hours): there the
    mean loss difference carries the change's own square, sparse and
    heavy-tailed, in its variance; this regression's variance carries only the
    errors left. Testing against 1/2 and not 0 keeps its size when the
    change's shape was itself chosen by looking at all the residuals (a gain
    block's hours): selection can give such a shape some correlation with the
    errors out of fold, not the weight of the better model.

    The lag length and the fixed-b reference are those of
    :func:`loss_difference_test` (q = 1 of
    :func:`bpsflow.diagnosis.structure.fixed_b_pvalue`).

    Parameters
    ----------
    errors_before, errors_after : ndarray
        Prediction errors (measured − predicted, output units) of the two
        models at the same hours, in time order. Hours where either is
        missing are dropped.
    weight : float
        ``λ`` under the null (-).
    lags : int, optional
        Newey–West lag length; default :func:`default_hac_lags` of the
        regression's scores, with the variance's bias under 2.5 %.
    reference : {"fixed-b", "normal"}
        Reference distribution of the t statistic.

    Returns
    -------
    dict
        ``slope`` (λ, -), ``weight``, ``statistic`` (t of ``λ − weight``),
        ``p_value`` (one-sided; 1 when the change is zero everywhere),
        ``lags``, ``n``, ``reference``.
    """
    import statsmodels.api as sm

    before, after = _paired(errors_before, errors_after)
    change = before - after
    n = before.size
    if n < 4:
        raise ValueError(f"the encompassing test needs at least 4 paired errors, got {n}")
    if np.std(change) <= 1e-12 * (1.0 + np.abs(change).max()):
        return {"slope": 0.0, "weight": weight, "statistic": 0.0, "p_value": 1.0, "lags": 0,
                "n": int(n), "reference": reference}
    design = np.column_stack([np.ones(n), change])
    residual = before - design @ np.linalg.lstsq(design, before, rcond=None)[0]
    if lags is None:
        lags = default_hac_lags((change - change.mean()) * residual, residual,
                                tolerance=LOSS_DIFFERENCE_BIAS_TOLERANCE)
    lags = min(int(lags), n - 1)
    ols = sm.OLS(before, design).fit(cov_type="HAC",
                                     cov_kwds={"maxlags": lags, "use_correction": True})
    slope = float(ols.params[1])
    statistic = (slope - weight) / float(ols.bse[1])
    p_value = _one_sided_p(statistic, lags, n, reference)
    return {"slope": slope, "weight": weight, "statistic": statistic, "p_value": p_value,
            "lags": int(lags), "n": int(n), "reference": reference}


def effective_fraction(residuals: np.ndarray) -> float:
    """Share of independent observations in autocorrelated residuals, n_eff / n (-).

    For an AR(1) series with lag-1 autocorrelation φ ≥ 0 the variance of a
    sum is that of ``n (1 + φ)/(1 − φ)`` independent terms, so the series
    carries ``(1 − φ)/(1 + φ)`` of its nominal information (Bayley &
    Hammersley, 1946, J. R. Stat. Soc. Suppl. 8: 184–197). A log-likelihood
    (and so a BIC) difference computed as if the hours were independent
    overstates the evidence by about the inverse of this share. A negative
    φ counts as 0 (no gain is claimed from it); φ is capped at 0.99.

    Parameters
    ----------
    residuals : ndarray
        Residuals in time order (output units); missing values are dropped.
    """
    values = np.asarray(residuals, dtype=float).ravel()
    values = values[np.isfinite(values)]
    if values.size < 3 or float(np.std(values)) == 0.0:
        return 1.0
    phi = min(max(float(autocorrelation(values, lags=1)[1]), 0.0), 0.99)
    return (1.0 - phi) / (1.0 + phi)


def bic(residuals: np.ndarray, n_parameters: int) -> float:
    """Bayesian information criterion of a fit with Gaussian errors (Schwarz, 1978).

    ``BIC = n ln(RSS/n) + k ln n`` (up to a constant common to models of the
    same data): lower is better, each extra parameter costs ``ln n``.

    Parameters
    ----------
    residuals : ndarray
        Residuals of the fit (output units); missing values are dropped.
    n_parameters : int
        Parameters fitted, k.
    """
    values = np.asarray(residuals, dtype=float).ravel()
    values = values[np.isfinite(values)]
    n = values.size
    if n == 0:
        raise ValueError("bic needs at least one residual")
    rss = float(values @ values)
    return float(n * math.log(rss / n) + n_parameters * math.log(n)) if rss > 0 else -math.inf
