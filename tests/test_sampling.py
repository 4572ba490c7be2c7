"""Sampling: marginals follow their distributions; LHS and Morris designs keep their structure."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import TypeAdapter
from scipy import stats

from bpsflow.distributions import Distribution
from bpsflow.sampling import latin_hypercube_unit, morris_unit, transform

ADAPTER = TypeAdapter(Distribution)

CONTINUOUS = [
    {"type": "uniform", "lower": 0.1, "upper": 0.4},
    {"type": "normal", "mean": 1.0, "std": 0.05, "lower": 0.9, "upper": 1.15},
    {"type": "normal", "mean": 0.0, "std": 2.0},
    {"type": "beta", "a": 2.0, "b": 5.0, "scale": 3.0, "shift": -1.0},
    {"type": "lognormal", "mu": 0.2, "sigma": 0.4},
    {"type": "triangular", "lower": 0.0, "mode": 0.3, "upper": 2.0},
]


class _P:
    def __init__(self, distribution):
        self.distribution = distribution
        self.name = "x"


@pytest.mark.parametrize("spec", CONTINUOUS, ids=lambda s: s["type"])
def test_lhs_marginals_pass_ks_against_their_distribution(spec):
    distribution = ADAPTER.validate_python(spec)
    unit = latin_hypercube_unit(4000, 3, random_state=11)
    values = transform(unit, [_P(distribution)] * 3)
    for column in range(3):
        assert stats.kstest(values[:, column], distribution.scipy().cdf).pvalue > 0.01
    if "lower" in spec and spec["type"] == "normal":
        assert values.min() >= spec["lower"] and values.max() <= spec["upper"]


def test_truncated_normal_differs_from_untruncated():
    # The KS test must be able to fail: an untruncated normal is not the truncated one.
    truncated = ADAPTER.validate_python({"type": "normal", "mean": 0, "std": 1, "lower": -0.5, "upper": 2})
    wide = stats.norm(0, 1).rvs(4000, random_state=3)
    assert stats.kstest(wide, truncated.scipy().cdf).pvalue < 1e-6


def test_lhs_has_one_point_per_stratum():
    unit = latin_hypercube_unit(50, 4, random_state=0)
    for column in range(4):
        assert sorted(np.floor(unit[:, column] * 50).astype(int)) == list(range(50))


def test_discrete_and_sampler_frequencies():
    discrete = ADAPTER.validate_python({"type": "discrete", "values": [3.0, 1.0, 2.0],
                                        "weights": [0.2, 0.5, 0.3]})
    u = latin_hypercube_unit(10000, 1, random_state=5)[:, 0]
    values = discrete.ppf(u)
    for value, weight in ((1.0, 0.5), (2.0, 0.3), (3.0, 0.2)):
        assert abs(np.mean(values == value) - weight) < 0.01
    sampler = ADAPTER.validate_python({"type": "sampler", "sequences": 400})
    index = sampler.ppf(latin_hypercube_unit(400, 1, random_state=2)[:, 0])
    assert sorted(index.astype(int)) == list(range(400))  # LHS picks every sequence once


def test_empirical_reads_file_and_reproduces_values(tmp_path):
    path = tmp_path / "gradient.txt"
    observed = np.array([0.6, 0.9, 1.1, 1.1, 1.7])
    np.savetxt(path, observed)
    empirical = ADAPTER.validate_python({"type": "empirical", "file": str(path)}).load(tmp_path)
    draws = empirical.ppf(latin_hypercube_unit(5000, 1, random_state=1)[:, 0])
    assert set(np.unique(draws)) == set(observed)
    assert abs(np.mean(draws == 1.1) - 0.4) < 0.02


def test_morris_steps_change_one_input_by_whole_levels():
    class Param:
        def __init__(self, name):
            self.name = name
    parameters = [Param(f"p{i}") for i in range(5)]
    unit = morris_unit(parameters, trajectories=6, levels=10, random_state=3)
    assert unit.shape == (6 * 6, 5)
    assert unit.min() > 0 and unit.max() < 1
    for trajectory in unit.reshape(6, 6, 5):
        steps = np.diff(trajectory, axis=0)
        changed = np.abs(steps) > 1e-12
        assert (changed.sum(axis=1) == 1).all()          # one input per step
        assert sorted(np.argmax(changed, axis=1)) == list(range(5))  # each input once
        levels = np.abs(steps[changed]) * 10
        assert np.allclose(levels, np.round(levels))


def test_bad_distribution_parameters_rejected():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="lower <= mode <= upper"):
        ADAPTER.validate_python({"type": "triangular", "lower": 0, "mode": 3, "upper": 2})
    with pytest.raises(ValidationError, match="hold no probability mass"):
        ADAPTER.validate_python({"type": "normal", "mean": 0, "std": 0.01, "lower": 5, "upper": 6})
