"""The deterministic baseline: bounded multi-start minimisation of w₁·NMBE² + w₂·CV(RMSE)².

Seed §4.3.5 compares Bayesian calibration with "a calibration using ...
non-linear optimization": only the parameters' bounds define the search
space, no model bias is considered, and the objective is a weighted sum of
the squared NMBE (eq. 1) and CV(RMSE) (eq. 2) (Reddy et al. 2007a), summed
over the calibrated outputs. Seed §2.3 notes that under flat priors and
Gaussian errors the posterior mode coincides with such a least-squares
estimate, which is why the optimum also serves as the sampler's start.

The search runs on the prior-CDF scale ``u ∈ (0, 1)^k`` (the bounds of every
parameter map to the unit cube) with L-BFGS-B from ``starts`` Latin hypercube
points; the gradient is a forward difference whose ``k + 1`` points are
predicted in one batch (one vectorised emulator or surrogate call).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from bpsflow.calibration.settings import DeterministicSettings
from bpsflow.metrics import cv_rmse, nmbe
from bpsflow.sampling import latin_hypercube_unit

#: Predicts every calibration row for a batch of unit-cube points: (B, k) -> (B, n).
Predictor = Callable[[np.ndarray], np.ndarray]

_BOUND = 1e-6
_STEP = 1e-4


def objective(observed: np.ndarray, predicted: np.ndarray, outputs: np.ndarray,
              nmbe_weight: float = 1.0, cv_rmse_weight: float = 1.0) -> float:
    """Σ over outputs of ``w₁·NMBE² + w₂·CV(RMSE)²`` (seed eq. 1–2; fractions).

    An output whose mean is near zero (NaN metrics) contributes its squared
    RMSE relative to its data range instead, so the search still sees it.
    """
    total = 0.0
    for output in np.unique(outputs):
        mine = outputs == output
        y, y_hat = observed[mine], predicted[mine]
        bias, spread = float(nmbe(y, y_hat)), float(cv_rmse(y, y_hat))
        if not (np.isfinite(bias) and np.isfinite(spread)):
            scale = max(float(np.ptp(y)), 1e-12)
            bias = float(np.mean(y - y_hat)) / scale
            spread = float(np.sqrt(np.mean((y - y_hat) ** 2))) / scale
        total += nmbe_weight * bias ** 2 + cv_rmse_weight * spread ** 2
    return total


@dataclass
class DeterministicResult:
    """The optimum and how it was found."""

    unit: np.ndarray                 # (k,) prior-CDF values of the optimum
    objective: float
    starts: list[dict]               # per start: objective and optimum (unit)
    evaluations: int
    seconds: float


def calibrate(predict: Predictor, observed: np.ndarray, outputs: np.ndarray, n_parameters: int,
              settings: DeterministicSettings) -> DeterministicResult:
    """Minimise the objective over the unit cube from several starts; keep the best.

    Parameters
    ----------
    predict : callable
        ``(B, k)`` unit-cube points -> ``(B, n)`` predicted calibration rows,
        in the outputs' units.
    observed : ndarray, shape (n,)
        Measured calibration rows.
    outputs : ndarray, shape (n,)
        Output name of each row.
    """
    started = time.perf_counter()
    evaluations = 0

    def batch_objectives(points: np.ndarray) -> np.ndarray:
        nonlocal evaluations
        evaluations += len(points)
        predicted = predict(points)
        return np.array([objective(observed, p, outputs, settings.nmbe_weight,
                                   settings.cv_rmse_weight) for p in predicted])

    def value_and_gradient(u: np.ndarray) -> tuple[float, np.ndarray]:
        steps = np.where(u + _STEP <= 1 - _BOUND, _STEP, -_STEP)
        points = np.vstack([u, u + np.diag(steps)])
        values = batch_objectives(points)
        return float(values[0]), (values[1:] - values[0]) / steps

    starts = np.vstack([np.full(n_parameters, 0.5),
                        latin_hypercube_unit(settings.starts, n_parameters, settings.seed)])
    starts = starts[:settings.starts]
    records = []
    best = None
    for start in starts:
        result = minimize(value_and_gradient, np.clip(start, _BOUND, 1 - _BOUND), jac=True,
                          method="L-BFGS-B", bounds=[(_BOUND, 1 - _BOUND)] * n_parameters,
                          options={"maxiter": 200})
        records.append({"start": start.tolist(), "unit": result.x.tolist(),
                        "objective": float(result.fun), "iterations": int(result.nit)})
        if best is None or result.fun < best.fun:
            best = result
    return DeterministicResult(unit=np.asarray(best.x), objective=float(best.fun), starts=records,
                               evaluations=evaluations, seconds=time.perf_counter() - started)
