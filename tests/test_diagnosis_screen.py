"""The extension screen's choices, on linear problems with a known answer.

* a law is screened with its best subset of terms: a one-term leak recovers its
  coefficient and beats the all-terms BIC by the penalty of the unneeded terms
  (three ln n, less a chi-square(3) fit gain);
* every family that improves on the current model is nominated, not only the
  best ``count`` causes, which one family's faces can fill.
"""

from __future__ import annotations

import math

import numpy as np

from bpsflow.diagnosis.extensions import EXTENSIONS, new_parameters
from bpsflow.diagnosis.fitting import Fit, parameter_range
from bpsflow.diagnosis.workflow import Model, _linearised_terms, _nominated


def _model(jacobian: np.ndarray, fitted: list) -> Model:
    n, k = jacobian.shape
    fit = Fit(parameters=fitted, values=np.zeros(k), prediction=np.zeros(n), jacobian=jacobian,
              covariance=np.eye(k), residual_std=1.0, objective=0.0, evaluations=0,
              seconds=0.0)
    return Model(config=None, fitted=fitted, fit=fit, label="test")  # type: ignore[arg-type]


def test_a_law_is_screened_with_its_best_terms_and_recovers_the_coefficient():
    rng = np.random.default_rng(7)
    n = 600
    terms = new_parameters(EXTENSIONS["infiltration"], "leak")
    assert [p.provenance["term"] for p in terms] == ["A", "B", "C", "D"]
    true_b = 0.5 * parameter_range(terms[1])[1]
    # per unit of each coefficient: the true B term moves the output by about 2 ± 1
    columns = (rng.normal(size=(n, len(terms))) + 2.0) / true_b
    noise = rng.normal(scale=0.05, size=n)
    residual = true_b * columns[:, 1] + noise
    current = _model(np.zeros((n, 0)), [])
    sample = {p.name: 0.0 for p in terms}
    cal = np.ones(n, dtype=bool)
    bic, values, lead = _linearised_terms(current, sample, terms, columns, residual,
                                          np.zeros((0, 2)), cal)
    assert lead is terms[1]
    assert abs(values[terms[1].name] - true_b) < 0.01 * true_b
    assert all(values[p.name] == 0.0 for p in (terms[0], terms[2], terms[3]))
    # the all-terms fit leaves less residual only by chance (n log RSS ratio ~ chi2(3),
    # under 11.34 with 99 %), and pays 3 ln n more
    solution, *_ = np.linalg.lstsq(columns, residual, rcond=None)
    left = residual - columns @ solution
    all_terms = n * math.log(float(left @ left) / n) + len(terms) * math.log(n)
    fit_gain = 3 * math.log(n) - (all_terms - bic)
    assert -1e-6 <= fit_gain < 11.34


def test_a_plain_extension_is_screened_with_every_parameter():
    rng = np.random.default_rng(8)
    n = 300
    free = new_parameters(EXTENSIONS["thermal_mass"], "mass")
    columns = rng.normal(size=(n, len(free)))
    residual = columns @ np.array([0.1, 0.0]) + rng.normal(scale=0.01, size=n)
    current = _model(np.zeros((n, 0)), [])
    _, values, lead = _linearised_terms(current, {p.name: 0.0 for p in free}, free, columns,
                                        residual, np.zeros((0, 2)), np.ones(n, dtype=bool))
    assert lead is free[0]
    assert set(values) == {p.name for p in free}


def test_every_improving_family_is_nominated():
    # four aperture faces fill the ranking; a mass one unit behind the second face
    families = ["solar_aperture"] * 4 + ["thermal_mass", "infiltration"]
    bics = [100.0, 101.0, 102.0, 103.0, 102.5, 130.0]
    ranked = [int(i) for i in np.argsort(bics)]
    chosen = _nominated(ranked, bics, families, 3, ceiling=120.0)
    assert chosen[:3] == [0, 1, 2]
    assert 4 in chosen            # the mass: improves on the current model
    assert 5 not in chosen        # the leak does not (BIC above the current model's)
    assert 3 not in chosen        # a fourth face: its family is already there
    assert _nominated(ranked, bics, ["same"] * 6, 3, ceiling=120.0) == [0, 1, 2]
