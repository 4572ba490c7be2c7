"""Characteristic signatures: can a plausible change of an existing parameter explain the residuals?

A parameter's characteristic signature is the model's response to a change
of that parameter, hour by hour (seed §1.1.1.1: calibration and
characteristic signatures, after Liu et al.; here computed by perturbation
runs rather than read from a catalogue). The residual left by the fitted
model is projected on each candidate's signature *after* removing what the
fitted parameters can already do (the span of the fit's Jacobian): the
projection coefficient is the change of the parameter that best explains
the residual, and its share of the residual variance says how much it
explains. A change is plausible when it stays within the parameter's
plausible range: its distribution's 1–99 % quantiles, or ± ``plausible_change``
(relative) around a fixed value.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from bpsflow.config import BoundaryTarget, Parameter
from bpsflow.diagnosis.fitting import Simulator
from bpsflow.distributions import Constant, Discrete, Empirical, Sampler


@dataclass
class Candidate:
    """A parameter that may be mis-valued, with its plausible range (its units)."""

    parameter: Parameter
    nominal: float
    lower: float
    upper: float


@dataclass
class Signature:
    """The model's hourly response per unit change of one parameter."""

    candidate: Candidate
    response: np.ndarray          # (n,) output units per parameter unit


@dataclass
class Explanation:
    """What the best change of one parameter does to the residuals."""

    name: str
    change: float                 # parameter units
    value: float                  # nominal + change
    plausible: bool
    share: float                  # share of the residual variance it explains
    corrected: np.ndarray         # residual minus the explained part (calibration hours)


def candidate_parameters(parameters: list[Parameter], fitted: list[str],
                         plausible_change: float) -> list[Candidate]:
    """Existing parameters that are not fitted and have a numeric value to change.

    Boundary sequence samplers and discrete/empirical choices are left out (no
    continuous change to project on); a fixed value of 0 has no relative range.
    """
    out = []
    for p in parameters:
        if p.name in fitted or any(isinstance(t, BoundaryTarget) for t in p.targets):
            continue
        distribution = p.distribution
        if isinstance(distribution, (Sampler, Discrete, Empirical)):
            continue
        nominal = float(distribution.nominal)
        if isinstance(distribution, Constant):
            if p.mode == "additive" or nominal == 0.0:
                continue
            half = abs(nominal) * plausible_change
            lower, upper = nominal - half, nominal + half
        else:
            lower, upper = (float(v) for v in distribution.ppf(np.array([0.01, 0.99])))
        if upper > lower:
            out.append(Candidate(p, nominal, lower, upper))
    return out


def signatures(simulate: Simulator, sample: dict[str, float], candidates: list[Candidate],
               prediction: np.ndarray, fraction: float = 0.2) -> list[Signature]:
    """Perturbation responses of each candidate (one batch of ``len(candidates)`` runs).

    Each candidate moves by ``fraction`` of its plausible half-range, towards
    the side with room; ``prediction`` is the unperturbed model at ``sample``.
    """
    if not candidates:
        return []
    rows, steps = [], []
    for c in candidates:
        step = fraction * (c.upper - c.lower) / 2
        if c.nominal + step > c.upper:
            step = -step
        row = dict(sample)
        row[c.parameter.name] = c.nominal + step
        rows.append(row)
        steps.append(step)
    predicted = simulate(pd.DataFrame(rows, index=pd.RangeIndex(len(rows), name="instance")))
    return [Signature(c, (p - prediction) / s) for c, p, s in zip(candidates, predicted, steps)]


def explain(residual: np.ndarray, fitted_jacobian: np.ndarray,
            found: list[Signature], calibration: np.ndarray,
            movable: np.ndarray | None = None) -> list[Explanation]:
    """Project the calibration-hour residual on each signature, net of the fitted span.

    ``movable`` (bool per fitted parameter) leaves out of the span the
    fitted parameters stuck at a bound of their range: they could not absorb
    more, so what lies along their direction is still to be explained.
    Returns the explanations sorted by explained share (largest first).
    """
    calibration = np.asarray(calibration, dtype=bool)
    r = np.asarray(residual, dtype=float)
    columns = fitted_jacobian[calibration]
    if movable is not None:
        columns = columns[:, np.asarray(movable, dtype=bool)]
    span = np.column_stack([np.ones(int(calibration.sum())), columns])
    projector = span @ np.linalg.pinv(span)
    r_free = r - projector @ r
    total = float(np.sum((r - r.mean()) ** 2))
    out = []
    for s in found:
        column = s.response[calibration]
        own = column - projector @ column
        norm = float(own @ own)
        if norm <= 1e-12 * max(float(column @ column), 1e-300):
            continue
        change = float(own @ r_free) / norm
        explained = change ** 2 * norm
        c = s.candidate
        value = c.nominal + change
        out.append(Explanation(name=c.parameter.name, change=change, value=value,
                               plausible=bool(c.lower <= value <= c.upper),
                               share=explained / total if total > 0 else 0.0,
                               corrected=r - change * own))
    return sorted(out, key=lambda e: -e.share)
