"""Known errors the calibration likelihood adds: the emulator's and the screened-out inputs'.

Both enter the likelihood of seed eq. 22 as a known covariance ``F Fᵀ +
diag(v)`` beside δ and σ_ε, through the same low-rank path (each column of
``F`` is one more row of the likelihood's Woodbury system):

* **the emulator's hold-out error** (``calibration.bayes.emulator_error:
  correlated``): each held-out design run's emulator error at every row;
* **the screened-out inputs' spread** (``calibration.screened_error``).
  Morris screening (seed §4.3.3, ``bpsflow sensitivity --screen``) fixes the
  inputs with small effects at their medians, so the emulator and the
  posterior take them as known. The building's own values are not their
  medians: the seed's own sensitivity ranking leaves 23 of Table A.7's inputs
  out, each small, together not small at hourly resolution. An ensemble of
  simulations with θ at its prior median and each screened-out input drawn
  (Latin hypercube) from the distribution it had before screening
  (``provenance.original_distribution``, written by the screening) measures
  that spread. The deviations of each run from the all-nominal run are the
  columns of ``F``: ``F Fᵀ`` is the second moment of the screened-out
  inputs' effect about the value the emulator assumes (their mean effect
  included, as one direction of ``F``). It is taken as independent of θ, a
  first-order treatment (Kennedy & O'Hagan 2001 §4.2 fix such inputs;
  Brynjarsdóttir & O'Hagan 2014 show what an unmodelled error does to θ).

References
----------
Kennedy, M. C. and O'Hagan, A. (2001). Bayesian calibration of computer
models. JRSS B 63(3), 425-464.
Brynjarsdóttir, J. and O'Hagan, A. (2014). Learning about physical parameters:
the importance of model discrepancy. Inverse Problems 30(11), 114007.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bpsflow.calibration.design import nominal_sample, unit_to_values
from bpsflow.calibration.emulator import Emulator
from bpsflow.config import Config, Parameter
from bpsflow.sampling import latin_hypercube_unit

#: Share of a known error's second moment its factor keeps as columns (the rest: diagonal).
FACTOR_SHARE = 0.99


def low_rank_second_moment(columns: np.ndarray, share: float = FACTOR_SHARE
                           ) -> tuple[np.ndarray, np.ndarray]:
    """``F`` (rows × r) and a per-row variance ``v`` with ``F Fᵀ + diag(v) ≈ C Cᵀ``.

    ``columns`` (rows × n) holds ``C``. ``F`` keeps the leading singular
    directions of ``C`` that hold ``share`` of ``trace(C Cᵀ)``; ``v`` puts
    the rest of each row's second moment back on the diagonal, so every row
    keeps its whole variance and only the weakest correlations are dropped.
    """
    columns = np.asarray(columns, dtype=float)
    vectors, values, _ = np.linalg.svd(columns, full_matrices=False)
    energy = np.cumsum(values ** 2) / max(float(np.sum(values ** 2)), 1e-300)
    keep = min(int(np.searchsorted(energy, share)) + 1, len(values))
    factor = vectors[:, :keep] * values[:keep]
    rest = np.clip(np.sum(columns * columns, axis=1) - np.sum(factor * factor, axis=1),
                   0.0, None)
    return factor, rest


def holdout_error_factor(emulator: Emulator, row_output: np.ndarray,
                         share: float = FACTOR_SHARE) -> tuple[np.ndarray, np.ndarray]:
    """``F`` (rows × r) and a per-row variance ``v`` with ``F Fᵀ + diag(v)`` the emulator's
    hold-out error covariance (standardised units).

    Each held-out run's error at every row, scaled by ``1/√runs``, is one
    column of the errors' empirical second moment: its diagonal is each
    row's mean squared error and its off-diagonal keeps how the errors of one
    run move together over the rows. An emulator's error at a given θ is a
    smooth function of the variable inputs, nearly the same over hundreds of
    hourly rows; counted as independent per row it averages away and θ
    absorbs it.
    """
    test = emulator.test
    assert test is not None
    std = emulator.scaling.y_std[row_output]
    errors = (test.simulated - test.predicted) / std[None, :]        # (test runs, rows)
    return low_rank_second_moment(errors.T / np.sqrt(len(errors)), share)


def screened_parameters(config: Config) -> list[Parameter]:
    """The inputs screening fixed, each with the distribution it had before.

    A parameter qualifies when its distribution is ``constant`` and its
    ``provenance`` carries ``original_distribution`` (what ``bpsflow
    sensitivity --screen`` writes).
    """
    screened = []
    for p in config.parameters:
        original = (p.provenance or {}).get("original_distribution")
        if p.distribution.type == "constant" and isinstance(original, dict):
            screened.append(Parameter.model_validate(
                {**p.model_dump(exclude={"distribution"}), "distribution": original}))
    return screened


def screened_samples(config: Config, screened: list[Parameter], runs: int,
                     seed: int) -> pd.DataFrame:
    """Run samples: instance 0 every input nominal, then ``runs`` Latin-hypercube draws of
    the screened-out inputs from their original distributions, every other input nominal
    (θ at its prior median)."""
    values = unit_to_values(latin_hypercube_unit(runs, len(screened), seed), screened)
    frame = pd.DataFrame([nominal_sample(config)] * (runs + 1),
                         index=pd.RangeIndex(runs + 1, name="instance"))
    for j, p in enumerate(screened):
        frame.loc[1:, p.name] = values[:, j]
    return frame


def screened_error_factor(simulated: np.ndarray, row_std: np.ndarray,
                          share: float = FACTOR_SHARE) -> tuple[np.ndarray, np.ndarray]:
    """``F`` (rows × r) and per-row ``v`` of the screened-out inputs' effect (standardised).

    Parameters
    ----------
    simulated : ndarray, shape (rows, 1 + n)
        Column 0 the all-nominal run, then the ``n`` ensemble runs, in the
        outputs' units.
    row_std : ndarray, shape (rows,)
        Each row's output scale (the emulator's standardisation).
    """
    deviations = (simulated[:, 1:] - simulated[:, :1]) / row_std[:, None]
    return low_rank_second_moment(deviations / np.sqrt(deviations.shape[1]), share)
