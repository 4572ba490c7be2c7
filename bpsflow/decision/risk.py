"""Underperformance probability and decision risk of an intervention (seed §4.4.2, eq. 23).

An intervention is judged by events on its predicted outcomes ("the week's
heating exceeds what was observed"); a decision rule implements it unless the
probability ``p`` that it underperforms (that any, or every, event of the rule
happens) exceeds a threshold. The decision risk is the probability that the
decision turns out wrong: ``p`` when the intervention is implemented (it
underperforms), ``1 - p`` when it is not (it would have worked), eq. 23.

The predictive distribution of each outcome combines parameter uncertainty
(posterior draws re-run on the physical model) with model bias: each draw's
prediction plus a random permutation of the errors that the same draw makes
on the test period (100 permutations per draw in the source, so 10,000
outcomes from 100 draws).

References
----------
Seed dissertation, chapter 4, §4.4.2 and eq. 23; Figures 4.10-4.11.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np


def decision_risk(p: float | np.ndarray, threshold: float = 0.5) -> float | np.ndarray:
    """Decision risk of eq. 23 from the underperformance probability ``p``.

    Parameters
    ----------
    p : float or ndarray
        Probability that the intervention underperforms (0..1).
    threshold : float, default 0.5
        The rule implements the intervention when ``p <= threshold``. The
        source's rules use 0.5, where eq. 23 reads ``p`` for ``p <= 0.5`` and
        ``1 - p`` above.

    Returns
    -------
    float or ndarray
        ``p`` where the intervention is implemented, ``1 - p`` where it is not.
    """
    p_arr = np.asarray(p, dtype=float)
    if np.any((p_arr < 0) | (p_arr > 1)):
        raise ValueError("an underperformance probability lies in [0, 1]")
    risk = np.where(p_arr <= threshold, p_arr, 1.0 - p_arr)
    return float(risk) if risk.ndim == 0 else risk


def permutation_orders(permutations: int, length: int, rng: np.random.Generator) -> np.ndarray:
    """``permutations`` random orders of ``length`` positions, shape (permutations, length)."""
    return np.argsort(rng.random((permutations, length)), axis=1)


def permuted_error_outcomes(prediction: np.ndarray, errors: np.ndarray,
                            outcome: Callable[[np.ndarray], np.ndarray], permutations: int,
                            rng: np.random.Generator, order: np.ndarray | None = None
                            ) -> np.ndarray:
    """Outcomes of one posterior draw with model bias added by permuting its test errors.

    Parameters
    ----------
    prediction : ndarray, shape (n,)
        The draw's predicted series over the test period (with the intervention).
    errors : ndarray, shape (n,)
        The same draw's errors on the test period, observed minus predicted
        (business as usual), aligned with ``prediction``.
    outcome : callable
        Maps series of shape (k, n) to ``k`` outcome values.
    permutations : int
        How many random permutations of ``errors`` to add.
    rng : numpy.random.Generator
        Source of the permutations (explicit, for reproducible results).
    order : ndarray, shape (permutations, n), optional
        The permutations to use instead of drawing them (so that several
        outputs of one draw share theirs, :func:`permutation_orders`).

    Returns
    -------
    ndarray, shape (permutations,)
        One outcome per permuted series ``prediction + errors[perm]``.

    Notes
    -----
    A sum over the period is unchanged by a permutation, so an outcome that
    is a total gets the draw's total error as a shift and no spread from the
    permutations; non-linear outcomes (discomfort) do get a spread.
    """
    prediction = np.asarray(prediction, dtype=float)
    errors = np.asarray(errors, dtype=float)
    if prediction.shape != errors.shape or prediction.ndim != 1:
        raise ValueError("prediction and errors must be 1-D series of one length")
    if order is None:
        order = permutation_orders(permutations, errors.size, rng)
    return np.asarray(outcome(prediction[None, :] + errors[order]), dtype=float)


def event_happens(projected: np.ndarray, reference: np.ndarray, factor: float = 1.0,
                  offset: float = 0.0, above: bool = True) -> np.ndarray:
    """Whether each projected outcome is above (or below) ``factor * reference + offset``."""
    bound = factor * np.asarray(reference, dtype=float) + offset
    projected = np.asarray(projected, dtype=float)
    return projected > bound if above else projected < bound


def underperformance_probability(events: Sequence[np.ndarray], combine: str = "any") -> float:
    """Share of predictive samples in which the rule's events say the intervention underperforms.

    Parameters
    ----------
    events : sequence of ndarray of bool, each shape (m,)
        Per event, whether it happens in each of the ``m`` joint predictive samples.
    combine : {"any", "all"}
        Underperformance when any event happens (the source's D1 and D2), or all.
    """
    stacked = np.vstack([np.asarray(e, dtype=bool) for e in events])
    happens = stacked.any(axis=0) if combine == "any" else stacked.all(axis=0)
    return float(happens.mean())


def accuracy_risk_correlation(accuracy: Mapping[str, Sequence[float]],
                              risks: Mapping[str, Sequence[float]]) -> dict[str, dict[str, float | None]]:
    """Pearson correlation across scenarios between each accuracy metric and each risk (Figure 4.11).

    ``None`` where a column is constant or has fewer than three finite pairs.
    """
    table: dict[str, dict[str, float | None]] = {}
    for metric, values in accuracy.items():
        row: dict[str, float | None] = {}
        for risk, risk_values in risks.items():
            a = np.asarray(values, dtype=float)
            b = np.asarray(risk_values, dtype=float)
            ok = np.isfinite(a) & np.isfinite(b)
            if ok.sum() < 3 or np.std(a[ok]) == 0 or np.std(b[ok]) == 0:
                row[risk] = None
            else:
                row[risk] = float(np.corrcoef(a[ok], b[ok])[0, 1])
        table[metric] = row
    return table


def correlation_caveats(risks: Mapping[str, Sequence[float]], outcomes_sampled: int,
                        alpha: float = 0.05, resolution_multiple: float = 5.0) -> list[str]:
    """What limits the accuracy–risk correlations across so few scenarios.

    A Pearson r over ``n`` scenarios is significant at ``alpha`` (two-sided) only
    above ``r_crit = t / sqrt(n − 2 + t²)``, ``t`` the Student quantile with
    ``n − 2`` degrees of freedom; and a risk that differs across the scenarios
    by no more than ``resolution_multiple`` sampled outcomes (a probability
    step is ``1 / outcomes_sampled``) moves by sampling noise alone.
    """
    from scipy import stats

    caveats = []
    count = max((len(v) for v in risks.values()), default=0)
    if count >= 3:
        t = float(stats.t.ppf(1 - alpha / 2, count - 2))
        critical = t / np.sqrt(count - 2 + t * t)
        caveats.append(f"{count} scenarios: |r| under {critical:.2f} is not significant at "
                       f"{alpha:.0%}")
    step = 1.0 / max(outcomes_sampled, 1)
    for name, values in risks.items():
        finite = np.asarray(values, dtype=float)
        finite = finite[np.isfinite(finite)]
        if finite.size and np.ptp(finite) <= resolution_multiple * step:
            caveats.append(f"{name} differs across the scenarios by {np.ptp(finite):.4g}, "
                           f"within {resolution_multiple:g} sampled outcomes ({step:.2g} each): "
                           "its correlations are sampling noise")
    return caveats
