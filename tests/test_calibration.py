"""Calibration: the emulator, KOH posterior, coverage, deterministic baseline, diagnostics, CLI.

Toy problems with known answers (seed §4.3): a smooth simulator the GP must
interpolate (and a full scikit-learn GP it must agree with), a simulator with
a known θ and a known added bias the posterior must recover, repeated truths
drawn from the model whose credible intervals must cover at their nominal
rate, a least-squares problem with a known optimum, chains that have not
mixed, and the command on a short surrogate config.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import special, stats
from typer.testing import CliRunner

from bpsflow.calibration import bayes
from bpsflow.calibration import emulator as emulator_module
from bpsflow.calibration.deterministic import calibrate as deterministic_calibrate
from bpsflow.calibration.deterministic import objective
from bpsflow.calibration.emulator import (
    GridEmulator,
    Hyperparameters,
    fit_emulator,
    fit_hyperparameters,
    grid_negative_log_likelihood,
    squared_exponential,
)
from bpsflow.calibration.settings import BayesSettings, DeterministicSettings, LogNormalPrior
from bpsflow.cli import app
from bpsflow.errors import BpsflowError
from bpsflow.sampling import latin_hypercube_unit

from conftest import i600_raw, write_config

bayes.configure_jax(2)


# ---------------------------------------------------------------------------
# Toy simulator: one variable input x, calibration parameters u in (0, 1)


def toy_simulator(x: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """η(x, u) for rows x (M,) and runs u (R, k) -> (M, R); smooth, nonlinear in u."""
    u = np.atleast_2d(unit)
    out = np.sin(3 * x)[:, None] * (0.5 + u[:, 0])[None, :] + 2.0 * x[:, None] * u[:, 0] ** 2
    if u.shape[1] > 1:
        out = out + np.cos(2 * x)[:, None] * u[:, 1][None, :]
    return out


def toy_emulator(k: int = 1, runs: int = 40, rows: int = 12, seed: int = 0):
    x = np.linspace(0.0, 1.0, rows)
    unit = latin_hypercube_unit(runs, k, seed)
    frame = pd.DataFrame({"x": x})
    outputs = pd.Series(["y"] * rows)
    emulator = fit_emulator(frame, outputs, toy_simulator(x, unit), unit, points=300,
                            test_fraction=0.1, random_state=seed)
    return x, unit, emulator


# ---------------------------------------------------------------------------
# Emulator


def test_grid_emulator_equals_the_full_gp_it_factorises():
    """The Kronecker form is exact: same mean and covariance as a GP on all R*M points."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    rng = np.random.default_rng(1)
    x = rng.normal(size=(7, 2))
    t = rng.normal(size=(9, 2))
    y = rng.normal(size=(9, 7))
    hyper = Hyperparameters(signal_variance=1.7, x_lengthscales=np.array([0.8, 1.3]),
                            t_lengthscales=np.array([1.1, 2.0]), nugget=0.05)
    grid = GridEmulator(x, t, y, hyper)
    inputs = np.array([np.r_[x[m], t[r]] for r in range(9) for m in range(7)])
    kernel = ConstantKernel(1.7) * RBF(np.r_[0.8, 1.3, 1.1, 2.0]) + WhiteKernel(0.05)
    gp = GaussianProcessRegressor(kernel, optimizer=None).fit(inputs, y.ravel())
    t_new = np.array([0.3, -0.4])
    query = np.hstack([x, np.repeat(t_new[None, :], 7, axis=0)])
    gp_noiseless = GaussianProcessRegressor(ConstantKernel(1.7) * RBF(np.r_[0.8, 1.3, 1.1, 2.0]),
                                            optimizer=None, alpha=0.05).fit(inputs, y.ravel())
    mean, cov = gp_noiseless.predict(query, return_cov=True)
    np.testing.assert_allclose(grid.predict_mean(t_new[None, :])[0], mean, atol=1e-9)
    np.testing.assert_allclose(grid.predict_cov(t_new), cov, atol=1e-9)
    np.testing.assert_allclose(gp.predict(query), mean, atol=1e-9)


def _dense_grid_covariance(x, t, hyper_values):
    s2, tau2, nugget, x_scales, t_scales = hyper_values
    kx = squared_exponential(x, x, x_scales) + tau2 * np.eye(len(x))
    return s2 * np.kron(squared_exponential(t, t, t_scales), kx), nugget


def test_grid_likelihood_and_gradient_are_the_dense_gaussian_ones():
    """The Kronecker likelihood equals the dense N(0, K) log density; its gradient, the
    central differences."""
    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(4)
    x, t, y = rng.normal(size=(11, 2)), rng.normal(size=(13, 3)), rng.normal(size=(13, 11))
    values = (1.3, 0.1, 0.02, np.array([1.2, 0.8]), np.array([2.0, 1.5, 0.7]))
    log_parameters = np.log(np.r_[values[:3], values[3], values[4]])
    nll, gradient = grid_negative_log_likelihood(log_parameters, x, t, y)
    cov, nugget = _dense_grid_covariance(x, t, values)
    dense = multivariate_normal(np.zeros(y.size), cov + nugget * np.eye(y.size))
    assert nll == pytest.approx(-dense.logpdf(y.ravel()), rel=1e-10)
    step = 1e-6
    numeric = [(grid_negative_log_likelihood(log_parameters + e, x, t, y)[0]
                - grid_negative_log_likelihood(log_parameters - e, x, t, y)[0]) / (2 * step)
               for e in np.eye(len(log_parameters)) * step]
    np.testing.assert_allclose(gradient, numeric, rtol=1e-6, atol=1e-6)


def test_grid_emulator_with_a_row_term_is_the_dense_gp():
    rng = np.random.default_rng(5)
    x, t, y = rng.normal(size=(6, 2)), rng.normal(size=(8, 2)), rng.normal(size=(8, 6))
    hyper = Hyperparameters(signal_variance=1.4, x_lengthscales=np.array([0.9, 1.1]),
                            t_lengthscales=np.array([1.3, 0.8]), nugget=0.03, row_variance=0.2)
    grid = GridEmulator(x, t, y, hyper)
    cov, nugget = _dense_grid_covariance(x, t, (1.4, 0.2, 0.03, hyper.x_lengthscales,
                                                hyper.t_lengthscales))
    t_new = np.array([[0.4, -0.2]])
    cross = 1.4 * np.kron(squared_exponential(t_new, t, hyper.t_lengthscales),
                          squared_exponential(x, x, hyper.x_lengthscales) + 0.2 * np.eye(6))
    solve = np.linalg.solve(cov + nugget * np.eye(48), np.c_[y.ravel(), cross.T])
    np.testing.assert_allclose(grid.predict_mean(t_new)[0], cross @ solve[:, 0], atol=1e-9)
    prior = 1.4 * (squared_exponential(x, x, hyper.x_lengthscales) + 0.2 * np.eye(6))
    np.testing.assert_allclose(grid.predict_cov(t_new[0]), prior - cross @ solve[:, 1:],
                               atol=1e-9)


def test_grid_fit_learns_each_rows_own_response():
    """Rows whose response to θ their variable input does not carry (as an hour's heating
    carries the building's thermal history): the grid fit finds a row term and predicts
    held-out runs much better than the scattered-point fit; on a smooth response it finds
    next to none."""
    rows, runs = 40, 60
    x = np.linspace(0.0, 1.0, rows)
    unit = latin_hypercube_unit(runs, 2, 3)
    own = np.random.default_rng(6).normal(size=rows)        # each row's own gain on θ
    simulated = toy_simulator(x, unit) + 0.3 * own[:, None] * np.sin(2.5 * unit[:, 0])[None, :]

    def fit(values, grid_fit):
        return fit_emulator(pd.DataFrame({"x": x}), pd.Series(["y"] * rows), values, unit,
                            points=300, test_fraction=0.2, random_state=1, grid_fit=grid_fit)

    grid, scattered = fit(simulated, True), fit(simulated, False)
    # τ² is relative to s²: the row term's own variance is s² τ²
    assert grid.hypers[0].signal_variance * grid.hypers[0].row_variance > 0.005
    assert scattered.hypers[0].row_variance == 0.0
    assert grid.test.rmse_standardised < 0.3 * scattered.test.rmse_standardised
    smooth = fit(toy_simulator(x, unit), True)
    assert smooth.hypers[0].signal_variance * smooth.hypers[0].row_variance < 1e-4
    assert smooth.test.r2 > 0.999


def test_emulator_interpolates_a_known_smooth_function():
    x, unit, emulator = toy_emulator(k=2, runs=60)
    assert emulator.test is not None and emulator.test.r2 > 0.999
    new = np.array([[0.21, 0.77], [0.64, 0.35], [0.9, 0.1]])
    predicted = emulator.scaling.y_back(emulator.grid.predict_mean(emulator.grid.t_of_unit(new)),
                                        np.array(["y"] * len(x)))
    truth = toy_simulator(x, new).T
    assert np.max(np.abs(predicted - truth)) < 0.02 * np.ptp(truth)


def test_value_inputs_are_the_standardised_value_in_numpy_and_in_the_sampler():
    """A lognormal parameter enters the emulator as its value, standardised by the prior's
    closed-form mean and standard deviation; the sampler's JAX map is the same; a prior
    with steps keeps the unit map."""
    import jax.numpy as jnp

    lognormal = stats.lognorm(s=0.88)
    discrete = stats.randint(0, 4)
    inputs = emulator_module.value_inputs(
        lambda unit: np.column_stack([lognormal.ppf(unit[:, 0]), discrete.ppf(unit[:, 1])]), 2)
    assert inputs.kinds == ("value", "unit")
    unit = np.array([[0.03, 0.2], [0.5, 0.5], [0.97, 0.9]])
    expected = (lognormal.ppf(unit[:, 0]) - lognormal.mean()) / lognormal.std()
    np.testing.assert_allclose(inputs.from_unit(unit)[:, 0], expected, rtol=2e-3, atol=2e-3)
    np.testing.assert_allclose(inputs.from_unit(unit)[:, 1], (unit[:, 1] - 0.5) * np.sqrt(12),
                               atol=1e-4)
    scores = np.array([-2.3, 0.4])
    sampler = np.asarray(bayes.emulator_inputs(jnp.asarray(scores), inputs.table))
    np.testing.assert_allclose(sampler, inputs.from_normal(scores[None, :])[0], atol=1e-12)


def two_output_problem(runs: int = 60, hours: int = 12, seed: int = 0):
    """Two outputs on interleaved rows: one bends fast in θ₁ and ignores θ₂, the other is
    linear in θ₂ and ignores θ₁ (what each wants of θ's length-scales is opposite)."""
    hour = np.repeat(np.linspace(0.0, 1.0, hours), 2)
    output = np.tile(["fast", "slow"], hours)
    unit = latin_hypercube_unit(runs, 2, seed)
    fast = np.sin(9.0 * unit[:, 0])[None, :] * (1.0 + hour[:, None])
    slow = 0.3 * unit[:, 1][None, :] + 0.2 * hour[:, None]
    simulated = np.where((output == "fast")[:, None], fast, slow)
    frame = pd.DataFrame({"hour": hour, "is_fast": (output == "fast").astype(float)})
    return frame, pd.Series(output), simulated, unit


def test_per_output_emulator_learns_each_outputs_own_lengthscales():
    """Each output's block has its own length-scales: the output that ignores a parameter
    puts it far out, the one that bends in it short; the shared GP must compromise, and
    predicts the slow output's held-out runs worse."""
    frame, output, simulated, unit = two_output_problem()
    own = fit_emulator(frame, output, simulated, unit, points=200, test_fraction=0.2)
    shared = fit_emulator(frame, output, simulated, unit, points=200, test_fraction=0.2,
                          per_output=False)
    assert own.grid.names == ("fast", "slow") and shared.grid.names == ("all",)
    fast, slow = own.hypers
    assert fast.t_lengthscales[0] < 1.0 < 20 * fast.t_lengthscales[0] < fast.t_lengthscales[1]
    assert slow.t_lengthscales[1] < slow.t_lengthscales[0] / 5
    # the indicator column is constant within a block: it has no length-scale there
    assert [len(h.x_lengthscales) for h in own.hypers] == [1, 1]
    assert own.test.per_output["slow"]["mse_standardised"] \
        < shared.test.per_output["slow"]["mse_standardised"]
    # the blocks' mean and covariance sit at their own rows; across blocks no covariance
    t = own.grid.t_of_unit(np.array([[0.3, 0.7]]))
    cov = own.grid.predict_cov(t[0])
    rows_fast, rows_slow = own.grid.rows
    assert np.all(cov[np.ix_(rows_fast, rows_slow)] == 0.0)
    np.testing.assert_allclose(own.grid.predict_mean(t)[0, rows_slow],
                               own.grid.blocks[1].predict_mean(t)[0])


def test_an_input_the_emulator_ignores_is_reported_only_where_the_runs_show_its_effect():
    """A length-scale at its bound is reported for the output the parameter moves, not for
    the output that truly ignores it."""
    from dataclasses import replace

    from bpsflow.calibration.workflow import LENGTHSCALE_AT_BOUND, ignored_inputs
    from bpsflow.config import Parameter

    frame, output, simulated, unit = two_output_problem()
    emulator = fit_emulator(frame, output, simulated, unit, points=150, test_fraction=0.0)
    parameters = [Parameter.model_validate({"name": n, "distribution": {"type": "uniform",
                                                                        "lower": 0, "upper": 1},
                                            "targets": [{"weather": "dry_bulb_temperature"}]})
                  for n in ("bends_fast", "moves_slow")]
    assert ignored_inputs(emulator, unit, parameters) == {}
    for block in emulator.grid.blocks:      # both parameters parked at the bound everywhere
        block.hyper = replace(block.hyper, t_lengthscales=np.full(2, LENGTHSCALE_AT_BOUND))
    assert ignored_inputs(emulator, unit, parameters) == {"fast": ["bends_fast"],
                                                          "slow": ["moves_slow"]}


@pytest.mark.parametrize("likelihood", ["exact", "lowrank"])
def test_per_output_emulator_likelihood_is_the_block_diagonal_gaussian(likelihood):
    """With one emulator block per output, observations listed in an order that mixes the
    blocks, the model's log density equals a hand-built Gaussian whose emulator covariance
    is the NumPy blocks' (block-diagonal; its diagonal for the low-rank likelihood)."""
    from numpyro.infer.util import log_density

    frame, output, simulated, unit = two_output_problem(runs=40, hours=8)
    emulator = fit_emulator(frame, output, simulated, unit, points=150, test_fraction=0.0)
    obs_rows = np.array([5, 0, 3, 2, 9, 12, 7, 4, 1, 14, 11])
    y = np.random.default_rng(6).normal(size=len(obs_rows))
    settings = BayesSettings(likelihood=likelihood, inducing_points=len(obs_rows), ard=True)
    data = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(2), settings)
    assert len(data.blocks) == 2
    point = {"z": np.array([0.4, -0.9]), "log_discrepancy_std": np.log(0.2),
             "log_discrepancy_lengthscale": np.array([-0.3, 0.2]),
             "log_noise_std": np.log(0.1)}
    model = bayes.make_model(True, data.priors, likelihood == "lowrank")
    value, _ = log_density(model, (bayes.model_arrays(data),), {}, point)
    t = emulator.grid.inputs.from_normal(point["z"][None, :])
    mean = emulator.grid.predict_mean(t)[0, obs_rows]
    cov = emulator.grid.predict_cov(t[0])[np.ix_(obs_rows, obs_rows)]
    if likelihood == "lowrank":
        cov = np.diag(np.diag(cov))
    xs = emulator.grid.x[obs_rows] / np.exp([-0.3, 0.2])
    d2 = ((xs[:, None, :] - xs[None, :, :]) ** 2).sum(-1)
    cov = cov + 0.2 ** 2 * np.exp(-0.5 * d2) + np.eye(len(y)) * (0.1 ** 2 + 1e-8)
    expected = stats.multivariate_normal(mean, cov).logpdf(y)
    priors = data.priors
    expected += stats.norm(0, 1).logpdf(point["z"]).sum()
    expected += stats.norm(*priors["log_discrepancy_std"]).logpdf(np.log(0.2))
    expected += stats.norm(*priors["log_discrepancy_lengthscale"]).logpdf([-0.3, 0.2]).sum()
    expected += stats.norm(*priors["log_noise_std"]).logpdf(np.log(0.1))
    assert float(value) == pytest.approx(expected, rel=1e-4)


def test_value_inputs_emulate_a_lognormal_effect_better_than_unit_inputs():
    """An output linear in a lognormal input's value bends sharply in the input's prior CDF;
    emulated on the value it is predicted an order of magnitude better on held-out runs."""
    lognormal = stats.lognorm(s=0.88)
    x = np.linspace(0.0, 1.0, 10)
    unit = latin_hypercube_unit(40, 1, 5)

    def simulator(u):
        return (1.0 + x)[:, None] * lognormal.ppf(np.atleast_2d(u)[:, 0])[None, :]

    errors = {}
    for kind, inputs in (("unit", emulator_module.unit_inputs(1)),
                         ("value", emulator_module.value_inputs(
                             lambda u: lognormal.ppf(u), 1))):
        emulator = fit_emulator(pd.DataFrame({"x": x}), pd.Series(["y"] * len(x)),
                                simulator(unit), unit, points=200, test_fraction=0.0,
                                random_state=0, inputs=inputs)
        new = np.array([[0.02], [0.3], [0.88], [0.985]])
        predicted = emulator.scaling.y_back(emulator.grid.predict_mean(
            emulator.grid.t_of_unit(new)), np.array(["y"] * len(x)))
        errors[kind] = np.max(np.abs(predicted - simulator(new).T))
    assert errors["value"] < 0.1 * errors["unit"]


def test_holdout_error_factor_keeps_each_rows_error_and_the_leading_correlation():
    """The correlated emulator error keeps few columns, each row's whole mean squared
    hold-out error (on the diagonal), and 99 % of the errors' second moment."""
    from bpsflow.calibration.known_error import holdout_error_factor

    _, _, emulator = toy_emulator(k=2, runs=120, rows=30)
    test = emulator.test
    row_output = np.zeros(30, dtype=int)
    errors = (test.simulated - test.predicted) / emulator.scaling.y_std[0]
    moment = errors.T @ errors / len(errors)
    factor, rest = holdout_error_factor(emulator, row_output, share=0.99)
    assert factor.shape[1] < len(errors)
    np.testing.assert_allclose(np.diag(factor @ factor.T) + rest, np.diag(moment), rtol=1e-9)
    kept = np.sum((factor @ factor.T) ** 2) ** 0.5 / np.sum(moment ** 2) ** 0.5
    assert kept > 0.98


def test_screened_error_factor_is_the_second_moment_about_the_nominal_run():
    """The screened-out inputs' factor: deviations from the nominal run (column 0), in each
    row's standardised units; with every direction kept ``F Fᵀ`` is their second moment
    (the mean offset included), and a truncated one keeps each row's whole variance."""
    from bpsflow.calibration.known_error import screened_error_factor

    rng = np.random.default_rng(8)
    rows, runs = 40, 25
    hours = np.linspace(0, 2 * np.pi, rows)
    nominal = 10 + np.sin(hours)
    # two screened-out inputs: an offset with a non-zero mean, and a daily shape
    effects = np.outer(np.ones(rows), 0.3 + rng.normal(0, 0.2, runs)) \
        + np.outer(np.cos(hours), rng.normal(0, 0.5, runs))
    simulated = np.column_stack([nominal, nominal[:, None] + effects])
    row_std = np.full(rows, 2.0)
    deviations = effects / 2.0
    moment = deviations @ deviations.T / runs
    full, rest = screened_error_factor(simulated, row_std, share=1.0)
    np.testing.assert_allclose(full @ full.T + np.diag(rest), moment, atol=1e-12)
    factor, rest = screened_error_factor(simulated, row_std, share=0.9)
    assert factor.shape[1] <= 2      # two inputs: at most two directions carry the moment
    np.testing.assert_allclose(np.diag(factor @ factor.T) + rest, np.diag(moment), rtol=1e-9)


def test_screened_parameters_take_their_original_distribution_and_a_latin_hypercube(tmp_path):
    """Only inputs screening fixed (constant, with ``provenance.original_distribution``) are
    spread; instance 0 is all nominal; the others draw each screened input once per stratum
    of its original distribution and keep every other input nominal."""
    from bpsflow.calibration.known_error import screened_parameters, screened_samples
    from bpsflow.config import load_config

    raw = i600_raw()
    names = [p["name"] for p in raw["parameters"] if p["distribution"]["type"] != "sampler"]
    fixed, plain = names[0], names[1]
    for p in raw["parameters"]:
        if p["name"] == fixed:
            p["provenance"] = {"original_distribution": {"type": "uniform", "lower": 0.5,
                                                         "upper": 1.5}}
            p["distribution"] = {"type": "constant", "value": 1.0}
        elif p["name"] == plain:
            p["distribution"] = {"type": "constant", "value": 2.0}   # fixed, no provenance
    config = load_config(write_config(tmp_path, raw))
    screened = screened_parameters(config)
    assert [p.name for p in screened] == [fixed]
    assert screened[0].distribution.type == "uniform"
    samples = screened_samples(config, screened, runs=20, seed=3)
    assert len(samples) == 21 and samples.index[0] == 0
    nominal = {p.name: p.distribution.nominal for p in config.parameters}
    assert samples.iloc[0].to_dict() == pytest.approx(nominal)
    strata = np.floor((samples[fixed].to_numpy()[1:] - 0.5) / 1.0 * 20).astype(int)
    assert sorted(strata) == list(range(20))
    others = samples.drop(columns=fixed).iloc[1:]
    assert np.allclose(others.to_numpy(), others.iloc[[0]].to_numpy())


def test_hyperparameter_fit_escapes_the_short_length_scale_basin(monkeypatch):
    """On a real design where one start falls into the all-nugget basin, the fit does not."""
    frame = pd.read_csv(Path(__file__).parent / "data" / "emulator_short_basin.csv", comment="#")
    x = frame.filter(regex=r"^x").to_numpy()
    t = frame.filter(regex=r"^t").to_numpy()
    y = frame["y"].to_numpy()
    fitted = fit_hyperparameters(x, t, y, restarts=0)
    # a simulator is deterministic: the nugget is numerical error, not most of the variance
    assert fitted.nugget < 0.01 * fitted.signal_variance
    assert len([n for n in fitted.notes if n.startswith("MLE from")]) == 1
    monkeypatch.setattr(emulator_module, "_MLE_STARTS", emulator_module._MLE_STARTS[:1])
    first_start_only = fit_hyperparameters(x, t, y, restarts=0)
    # the data really have the trap: from the first start alone the nugget takes over
    assert first_start_only.nugget > 0.05
    assert fitted.log_marginal_likelihood > first_start_only.log_marginal_likelihood + 100


def test_squared_exponential_is_the_seed_kernel():
    a, b = np.array([[0.0, 1.0]]), np.array([[1.0, 3.0]])
    lengthscales = np.array([2.0, 4.0])
    expected = np.exp(-0.5 * ((1 / 2) ** 2 + (2 / 4) ** 2))   # seed eq. 20 with beta = 1/l^2
    assert squared_exponential(a, b, lengthscales)[0, 0] == pytest.approx(expected)


# ---------------------------------------------------------------------------
# KOH posterior


def _koh(emulator, observed: np.ndarray, obs_rows: np.ndarray, settings: BayesSettings,
         laplace: bool = True, timed_warmup: bool = True):
    y = emulator.scaling.y(observed, np.array(["y"] * len(observed)))
    data = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(emulator.grid.t.shape[1]),
                          settings)
    mass = None
    if laplace:
        start = {k: v[0] for k, v in bayes.initial_values(data, None, 1, 0, spread=0.0).items()}
        approx = bayes.laplace(data, start)
        init, mass = bayes.laplace_starts(approx, settings.chains, settings.seed), approx.covariance
    else:
        init = bayes.initial_values(data, None, settings.chains, settings.seed)
    posterior = bayes.sample_posterior(data, settings, init, inverse_mass_matrix=mass,
                                       timed_warmup=timed_warmup)
    return data, y, posterior


@pytest.mark.slow
def test_posterior_concentrates_on_theta_and_discrepancy_recovers_the_bias():
    x, unit, emulator = toy_emulator(k=1, runs=40, rows=16)
    truth, bias = 0.3, 0.25
    rng = np.random.default_rng(4)
    obs_rows = np.arange(12)
    observed = toy_simulator(x, np.array([[truth]]))[:, 0][obs_rows] + bias \
        + 0.01 * rng.standard_normal(len(obs_rows))
    settings = BayesSettings(chains=2, warmup=300, samples=400, seed=1)
    data, y, posterior = _koh(emulator, observed, obs_rows, settings)
    u = special.ndtr(bayes.flat_draws(posterior)["z"][:, 0])
    assert abs(np.median(u) - truth) < 0.05
    assert np.std(u) < 0.5 * np.sqrt(1 / 12)        # contracted from the uniform prior
    flat = bayes.flat_draws(posterior)
    pick = np.arange(0, len(u), 8)
    pred = bayes.predictive(emulator.grid, obs_rows, obs_rows, y, u[pick, None],
                            flat["log_discrepancy_std"][pick],
                            flat["log_discrepancy_lengthscale"][pick],
                            flat["log_noise_std"][pick], ard=False)
    delta = pred.discrepancy.mean() * emulator.scaling.y_std[0]
    assert delta == pytest.approx(bias, abs=0.06)
    assert bayes.assess(posterior, {"z": ["theta"]}, settings).per_quantity["theta"]["rhat"] < 1.02


@pytest.mark.slow
def test_credible_intervals_cover_at_their_nominal_rate():
    """Truths drawn from the model itself: 90 % and 50 % intervals cover ~90 % and ~50 %."""
    x, unit, emulator = toy_emulator(k=2, runs=40, rows=8, seed=2)
    rng = np.random.default_rng(11)
    settings = BayesSettings(chains=1, warmup=100, samples=200, seed=3)
    obs_rows = np.arange(8)
    xs = emulator.grid.x[obs_rows]
    d2 = (xs - xs.T) ** 2
    covered90 = covered50 = total = 0
    for _trial in range(12):
        u_true = rng.uniform(size=2)
        sd_delta = np.exp(rng.normal(np.log(0.2), 0.5))
        lengthscale = np.exp(rng.normal(0.0, 0.75))
        sd_eps = np.exp(rng.normal(np.log(0.05), 0.5))
        eta = emulator.grid.predict_mean(emulator.grid.t_of_unit(u_true[None, :]))[0, obs_rows]
        delta = rng.multivariate_normal(np.zeros(8), sd_delta ** 2 * np.exp(-0.5 * d2 / lengthscale ** 2)
                                        + 1e-12 * np.eye(8))
        y = eta + delta + sd_eps * rng.standard_normal(8)
        observed = emulator.scaling.y_back(y, np.array(["y"] * 8))
        _, _, posterior = _koh(emulator, observed, obs_rows, settings, laplace=False,
                               timed_warmup=False)
        u = special.ndtr(bayes.flat_draws(posterior)["z"])
        for j in range(2):
            covered90 += np.quantile(u[:, j], 0.05) <= u_true[j] <= np.quantile(u[:, j], 0.95)
            covered50 += np.quantile(u[:, j], 0.25) <= u_true[j] <= np.quantile(u[:, j], 0.75)
            total += 1
    # two-sided binomial tests at the 1 % level
    assert stats.binomtest(covered90, total, 0.9).pvalue > 0.01, covered90
    assert stats.binomtest(covered50, total, 0.5).pvalue > 0.01, covered50


# ---------------------------------------------------------------------------
# Deterministic baseline


def test_compiled_programs_are_kept_where_the_user_says_or_not_at_all(tmp_path, monkeypatch):
    """The NUTS programs' disk cache: a named folder, ``off``, or the user cache by default;
    a folder that cannot be written leaves it off instead of failing the calibration."""
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home-cache"))
    monkeypatch.delenv(bayes.COMPILATION_CACHE_ENV, raising=False)
    assert bayes.compilation_cache_dir() == tmp_path / "home-cache" / "bpsflow" / "jax"
    monkeypatch.setenv(bayes.COMPILATION_CACHE_ENV, str(tmp_path / "mine"))
    assert bayes.compilation_cache_dir() == tmp_path / "mine"
    for off in ("off", "OFF", "0"):
        monkeypatch.setenv(bayes.COMPILATION_CACHE_ENV, off)
        assert bayes.compilation_cache_dir() is None
        assert bayes.enable_compilation_cache() is None
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    monkeypatch.setenv(bayes.COMPILATION_CACHE_ENV, str(blocked / "jax"))
    assert bayes.enable_compilation_cache() is None


def test_deterministic_optimiser_finds_a_known_optimum():
    x = np.linspace(0, 1, 20)
    target = np.array([0.23, 0.71])

    def predict(unit):
        unit = np.atleast_2d(unit)
        return 100 + 50 * unit[:, :1] * np.sin(4 * x)[None, :] + 30 * unit[:, 1:2] * x[None, :] ** 2

    observed = predict(target)[0]
    result = deterministic_calibrate(predict, observed, np.array(["y"] * 20), 2,
                                     DeterministicSettings(starts=4, seed=1))
    np.testing.assert_allclose(result.unit, target, atol=1e-3)
    assert result.objective < 1e-8
    assert objective(observed, observed * 1.1, np.array(["y"] * 20)) > 0


# ---------------------------------------------------------------------------
# Diagnostics


def test_diagnostics_known_answers():
    rng = np.random.default_rng(0)
    iid = rng.standard_normal((4, 1000))
    assert bayes.rhat(iid) < 1.01
    assert 3000 < bayes.ess_bulk(iid) < 5000
    assert 2500 < bayes.ess_tail(iid) < 5500
    apart = iid + np.array([0.0, 0.0, 3.0, 3.0])[:, None]     # chains that never met
    assert bayes.rhat(apart) > 1.5
    sticky = np.cumsum(rng.standard_normal((4, 1000)), axis=1)  # random walks
    assert bayes.ess_bulk(sticky) < 100


@pytest.mark.slow
def test_unmixed_chains_are_reported_as_not_converged():
    x, unit, emulator = toy_emulator(k=1, runs=30, rows=8)
    observed = toy_simulator(x, np.array([[0.4]]))[:, 0]
    settings = BayesSettings(chains=2, warmup=1, samples=20, seed=0)
    _, _, posterior = _koh(emulator, observed, np.arange(8), settings, laplace=False)
    convergence = bayes.assess(posterior, {"z": ["theta"]}, settings)
    assert not convergence.converged
    assert any("ESS" in reason for reason in convergence.reasons)


@pytest.mark.slow
def test_extended_chains_are_the_chains_a_longer_run_draws():
    x, unit, emulator = toy_emulator(k=1, runs=30, rows=8)
    observed = toy_simulator(x, np.array([[0.4]]))[:, 0]
    short = BayesSettings(chains=2, warmup=50, samples=30, seed=3)
    long = short.model_copy(update={"samples": 90})
    _, _, posterior = _koh(emulator, observed, np.arange(8), short, laplace=False)
    _, _, reference = _koh(emulator, observed, np.arange(8), long, laplace=False)
    extended = bayes.extend_posterior(bayes.extend_posterior(posterior))
    assert extended.extensions == 2 and extended.draws["z"].shape[:2] == (2, 90)
    # warm-up is not repeated and each chain carries on from its own state and key
    np.testing.assert_allclose(extended.draws["z"], reference.draws["z"], rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(extended.num_steps, reference.num_steps)
    assert extended.warmup_num_steps.shape == posterior.warmup_num_steps.shape


# ---------------------------------------------------------------------------
# The command on a short surrogate config


def _short_calibration_config(tmp_path, scenarios: bool = False, screened: bool = False,
                              calibration: dict | None = None) -> tuple:
    """``screened``: the fixed inputs carry their distribution as screening writes it, and
    the calibration spreads them (``calibration.screened_error``)."""
    raw = i600_raw()
    raw["model"]["backend"] = "surrogate"
    raw["model"]["periods"] = [{"name": "cal", "start": "11-08", "end": "11-19"}]
    raw["model"]["tests"] = [{"name": "H", "period": "cal", "start": "11-08", "days": 12,
                              "warmup_days": 2, "mode": "heating", "setpoint_c": 30.0,
                              "setback_c": 24.0,
                              "outputs": ["heating_power_w", "zone_air_temperature_c"]}]
    keep = {"glazing_dirt_correction", "wall_stack_coefficient"}
    for parameter in raw["parameters"]:
        if parameter["name"] not in keep:
            distribution = parameter["distribution"]
            value = {"uniform": lambda d: (d["lower"] + d["upper"]) / 2,
                     "normal": lambda d: d["mean"], "sampler": lambda d: 0}[distribution["type"]]
            parameter["distribution"] = {"type": "constant", "value": float(value(distribution))}
            if screened and distribution["type"] != "sampler":
                parameter["provenance"] = {"original_distribution": distribution}
    raw["calibration"] = {
        "outputs": ["heating_power_w"], "resolution": "daily", "holdout_days": 3,
        "design": {"runs": 40, "seed": 1}, "emulator": {"points": 200},
        "bayes": {"chains": 2, "warmup": 150, "samples": 150, "ess_min": 50, "rhat_max": 1.1},
        "deterministic": {"starts": 2}, "posterior_runs": 10}
    if screened:
        raw["calibration"]["screened_error"] = {"runs": 8, "seed": 2}
    raw["calibration"].update(calibration or {})
    if scenarios:
        raw["calibration"]["scenarios"] = [
            {"name": "D-E", "outputs": ["heating_power_w"], "resolution": "daily"},
            {"name": "D-ET", "outputs": ["heating_power_w", "zone_air_temperature_c"],
             "resolution": "daily"}]
    config = write_config(tmp_path, raw)
    truth = tmp_path / "truth.yaml"
    truth.write_text("seed: 1\nvalues: {glazing_dirt_correction: 0.9, wall_stack_coefficient: 1.2}\n")
    runner = CliRunner()
    result = runner.invoke(app, ["synth", str(config), "--truth", str(truth)])
    assert result.exit_code == 0, result.output
    return config, tmp_path / "run" / "truth" / "measured.csv", tmp_path / "run" / "truth" / "truth.json"


@pytest.mark.slow
def test_cli_calibrate_writes_the_documented_files(tmp_path):
    config, measured, truth = _short_calibration_config(tmp_path, screened=True)
    result = CliRunner().invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                      "--truth", str(truth), "--no-progress",
                                      "--allow-unconverged"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "run" / "calibration"
    for name in ("calibration.json", "posterior.parquet", "heldout.csv", "observations.parquet",
                 "emulator_points.parquet", "figures/prior_posterior.png",
                 "figures/emulator_test.png", "figures/heldout_heating_power_w_daily.png",
                 "figures/trace.png"):
        assert (out / name).is_file(), name
    record = json.loads((out / "calibration.json").read_text())
    diagnostics = record["diagnostics"]
    assert diagnostics["rhat_max"] < 1.2 and diagnostics["steps_per_iteration"] > 0
    assert {"ess_bulk_min", "ess_tail_min", "divergences", "min_ess_per_second",
            "converged"} <= set(diagnostics)
    assert {p["name"] for p in record["parameters"]} == {"glazing_dirt_correction",
                                                         "wall_stack_coefficient"}
    assert all("contraction" in p and "truth_in_90" in p for p in record["parameters"])
    at_bound = [p["name"] for p in record["parameters"] if p["emulator_lengthscale"] >= 999]
    if not at_bound:
        assert "the emulator finds no effect of" not in " ".join(result.output.split())
    assert record["emulator"]["holdout"]["r2"] > 0.99
    # the fixed inputs' spread: 8 runs + the nominal one, measured and in the likelihood
    spread = record["screened_error"]
    assert spread["runs"] == 8 and spread["components"] >= 1
    assert spread["rms_standardised"]["heating_power_w"] > 0
    assert "glazing_dirt_correction" not in spread["inputs"] and len(spread["inputs"]) > 5
    assert len(pd.read_parquet(out / "screened_error" / "results.parquet")["instance"]
               .unique()) == 9
    models = {row["model"] for row in record["heldout"]}
    assert models == {"prior", "bayes_gp", "bayes_physical", "deterministic_physical"}
    posterior = pd.read_parquet(out / "posterior.parquet")
    assert len(posterior) == 2 * 150
    # the physical check re-runs the held-out days after their warm-up, not the whole period
    design_times = pd.read_parquet(out / "design" / "results.parquet")["timestamp"]
    rerun_times = pd.read_parquet(out / "posterior_runs" / "results.parquet")["timestamp"]
    assert rerun_times.max() == design_times.max() and rerun_times.min() > design_times.min()
    assert {"chain", "draw", "glazing_dirt_correction", "noise_std"} <= set(posterior.columns)


@pytest.mark.slow
def test_refinement_runs_posterior_draws_and_the_emulator_errs_less_where_the_posterior_is(
        tmp_path):
    """With a design too thin for the emulator, runs at posterior draws are added and the
    posterior sampled again: the refined emulator's error at the next posterior's draws
    (round 2's record) is below the first emulator's at the first posterior's (round 1).

    Hourly rows, where each hour's response to θ is its own: at daily resolution this
    two-input response is nearly linear, and ten runs already emulate it at the error
    floor (both rounds about 0.002), so the comparison there would rest on noise."""
    config, measured, truth = _short_calibration_config(tmp_path, calibration={
        "design": {"runs": 10, "seed": 3}, "refinement": {"runs": 10, "rounds": 2, "seed": 1},
        "resolution": "hourly"})
    result = CliRunner().invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                      "--truth", str(truth), "--no-progress",
                                      "--allow-unconverged"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "run" / "calibration"
    record = json.loads((out / "calibration.json").read_text())
    rounds = record["refinement"]["rounds"]
    assert [r["design_runs"] for r in rounds] == [20, 30]
    # the final emulator is conditioned on the design runs and both rounds'
    assert record["emulator"]["runs"] == 30
    errors = [r["emulator_error_at_posterior"]["heating_power_w"] for r in rounds]
    assert errors[1] < errors[0], errors
    for number in (1, 2):
        samples = pd.read_parquet(out / "refinement" / f"round{number}" / "samples.parquet")
        assert len(samples) == 10
        assert samples["instance"].min() == 10 * number
    assert "refinement round 2" in " ".join(result.output.split())


@pytest.mark.slow
def test_decide_takes_the_physical_checks_runs_of_the_held_out_week(tmp_path):
    """On the held-out days decide uses the check's runs of the same draws (none simulated
    again) and decides exactly as when it simulates them; another week is simulated."""
    config, measured, _ = _short_calibration_config(tmp_path)
    result = CliRunner().invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                      "--no-progress", "--allow-unconverged"])
    assert result.exit_code == 0, result.output
    calibration = tmp_path / "run" / "calibration"
    upgraded = next(p for p in yaml.safe_load(config.read_text())["parameters"]
                    if p["name"] == "south_wall_insulation_conductivity")
    upgraded["distribution"]["value"] /= 2
    decision = calibration / "decision" / "thicker_insulation_11_17"

    def decide(start: str) -> dict:
        intervention = tmp_path / f"upgrade_{start}.yaml"
        # one name per week: a decision of the same name and other content is refused
        intervention.write_text(yaml.safe_dump({
            "name": f"thicker_insulation_{start.replace('-', '_')}",
            "change": {"overlay": {"parameters": [upgraded]}},
            "week": {"start": start, "days": 3},
            "outcomes": [{"name": "heat", "output": "heating_power_w", "statistic": "total"}],
            "rules": [{"name": "saves", "threshold": 0.5,
                       "events": [{"outcome": "heat", "above": {"factor": 1.0}}]}],
            # the draws the check re-ran (calibration.posterior_runs)
            "sampling": {"posterior_draws": 10, "permutations": 20, "seed": 1}}))
        result = CliRunner().invoke(app, ["decide", str(config), "--calibration", str(calibration),
                                          "--intervention", str(intervention), "--no-progress"])
        assert result.exit_code == 0, result.output
        return {"output": result.output, "decision": json.loads(
            (decision.with_name(f"thicker_insulation_{start.replace('-', '_')}")
             / "decision.json").read_text())}

    reused = decide("11-17")          # the held-out days (holdout_days 3, the test ends 11-19)
    assert "its runs are used" in reused["output"]
    assert not (decision / "runs_as_is").exists()
    (calibration / "posterior_runs" / "window.json").unlink()
    simulated = decide("11-17")
    assert "its runs are used" not in simulated["output"]
    assert (decision / "runs_as_is" / "results.parquet").is_file()
    assert simulated["decision"]["rules"] == reused["decision"]["rules"]
    # the measured file is recorded, and the earlier decision is moved aside, not overwritten
    assert simulated["decision"]["measured"] == str(measured.resolve())
    converged = json.loads((calibration / "calibration.json").read_text())[
        "diagnostics"]["converged"]
    assert simulated["decision"]["calibration_converged"] is converged
    assert ("did not converge" in simulated["output"]) is (not converged)
    assert len(list((decision / "previous").glob("*/decision.json"))) == 1
    assert "the earlier decision" in " ".join(simulated["output"].split())
    assert "parameter south_wall_insulation_conductivity:" in " ".join(
        simulated["output"].split())
    assert "its runs are used" not in decide("11-14")["output"]


@pytest.mark.slow
def test_cli_exits_non_zero_when_not_converged(tmp_path):
    bayes_settings = {"chains": 2, "warmup": 150, "samples": 150, "ess_min": 50,
                      "rhat_max": 1.1, "extend": 2}
    config, measured, _ = _short_calibration_config(tmp_path,
                                                    calibration={"bayes": bayes_settings})
    args = ["calibrate", str(config), "--measured", str(measured), "--no-progress",
            "--warmup", "1", "--samples", "20"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1, result.output
    assert "not converged" in result.output.lower()
    record = json.loads((tmp_path / "run" / "calibration" / "calibration.json").read_text())
    diagnostics = record["diagnostics"]
    assert diagnostics["converged"] is False and diagnostics["reasons"]
    # one warm-up step leaves divergent chains, which longer chains do not cure
    assert diagnostics["extensions"] == 0 and diagnostics["samples_per_chain"] == 20
    # warmed up but too short for ess_min 50: the chains carry on, 20 draws at a time
    args[-3] = "150"
    result = CliRunner().invoke(app, args)
    diagnostics = json.loads((tmp_path / "run" / "calibration" / "calibration.json")
                             .read_text())["diagnostics"]
    assert diagnostics["extensions"] >= 1, result.output
    assert diagnostics["samples_per_chain"] == 20 * (1 + diagnostics["extensions"])
    assert "extension 1 of 2" in " ".join(result.output.split())
    assert diagnostics["converged"] or diagnostics["extensions"] == 2
    assert result.exit_code == (0 if diagnostics["converged"] else 1), result.output


@pytest.mark.slow
def test_cli_scenarios_and_deterministic(tmp_path):
    config, measured, _ = _short_calibration_config(tmp_path, scenarios=True)
    # Convergence of these 150-draw chains depends on the NumPyro/JAX release (tail ESS 43
    # against ess_min 50 with 0.22/0.10); it has its own test. This one checks the files.
    result = CliRunner().invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                      "--scenarios", "--no-progress", "--allow-unconverged"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "run" / "calibration"
    table = pd.read_csv(out / "scenarios.csv")
    assert list(table["scenario"]) == ["D-E", "D-ET"]
    assert "contraction:wall_stack_coefficient" in table.columns
    assert (out / "scenarios" / "D-ET" / "calibration.json").is_file()
    assert (out / "figures" / "scenarios.png").is_file()
    result = CliRunner().invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                      "--method", "deterministic", "--out",
                                      str(tmp_path / "det"), "--no-progress"])
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "det" / "calibration.json").read_text())
    assert record["diagnostics"] is None
    assert {row["model"] for row in record["heldout"]} == {"prior", "deterministic_physical"}


@pytest.mark.slow
def test_deterministic_on_the_simulator_agrees_with_the_emulator(tmp_path):
    import yaml

    config, measured, _ = _short_calibration_config(tmp_path)
    out = {}
    for model in ("emulator", "simulator"):
        raw = yaml.safe_load(config.read_text())
        raw["calibration"]["deterministic"].update(model=model, starts=1)
        if model == "simulator":       # more fit points than the runs hold: said, not silent
            raw["calibration"]["emulator"]["points"] = 100_000
        path = tmp_path / f"{model}.yaml"
        path.write_text(yaml.safe_dump(raw))
        result = CliRunner().invoke(app, ["calibrate", str(path), "--measured", str(measured),
                                          "--method", "deterministic", "--out",
                                          str(tmp_path / model), "--no-progress"])
        assert result.exit_code == 0, result.output
        said = "note: calibration.emulator.points is 100000, but the training runs hold only"
        assert (said in " ".join(result.output.split())) == (model == "simulator")
        record = json.loads((tmp_path / model / "calibration.json").read_text())
        out[model] = {p["name"]: p["deterministic"] for p in record["parameters"]}
    # the emulator reproduces the simulator, so both optima agree
    assert out["simulator"]["glazing_dirt_correction"] == pytest.approx(
        out["emulator"]["glazing_dirt_correction"], abs=0.02)
    assert out["simulator"]["wall_stack_coefficient"] == pytest.approx(
        out["emulator"]["wall_stack_coefficient"], abs=0.1)


def test_bad_calibration_input_names_the_key(tmp_path):
    config, measured, _ = _short_calibration_config(tmp_path)
    result = CliRunner().invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                      "--outputs", "no_such_output"])
    assert result.exit_code == 2
    assert "--outputs: 'no_such_output' is not an output" in " ".join(result.output.split())


@pytest.mark.slow
def test_hourly_coverage_holds_under_a_known_model_form_error():
    """Many rows ("hourly") and a structured error the simulator lacks: δ(x) must absorb it.

    The field is the simulator plus a daily-cycle error written apart from δ's
    prior (a sine of period a quarter of the range, not a GP draw) plus noise.
    With δ the 90 % intervals of θ cover the truths at their rate; with δ
    switched off (its prior pinned near zero; σ_ε known in both) θ absorbs the
    error and they do not, so the check has power.
    """
    rows = 60
    x, unit, emulator = toy_emulator(k=2, runs=50, rows=rows, seed=5)
    obs_rows = np.arange(rows)
    rng = np.random.default_rng(21)
    noise_sd = 0.02
    noise = LogNormalPrior(median=noise_sd / emulator.scaling.y_std[0], log_sd=0.1)
    with_delta = BayesSettings(chains=1, warmup=150, samples=200, seed=2, laplace=False,
                               noise_std=noise)
    without = with_delta.model_copy(
        update={"discrepancy_std": LogNormalPrior(median=1e-4, log_sd=0.01)})
    covered = {"with": 0, "without": 0}
    total = 0
    for _trial in range(6):
        u_true = rng.uniform(0.1, 0.9, size=2)
        model_form = 0.25 * np.sin(2 * np.pi * 4 * x) + 0.1 * (x > 0.5)
        observed = toy_simulator(x, u_true[None, :])[:, 0] + model_form \
            + noise_sd * rng.standard_normal(rows)
        for name, settings in (("with", with_delta), ("without", without)):
            _, _, posterior = _koh(emulator, observed, obs_rows, settings, laplace=False,
                                   timed_warmup=False)
            u = special.ndtr(bayes.flat_draws(posterior)["z"])
            covered[name] += sum(np.quantile(u[:, j], 0.05) <= u_true[j]
                                 <= np.quantile(u[:, j], 0.95) for j in range(2))
        total += 2
    assert covered["with"] / total >= 0.75, covered
    assert stats.binomtest(covered["with"], total, 0.9).pvalue > 0.01, covered
    assert covered["without"] / total <= 0.5, covered


def test_per_output_noise_is_the_gaussian_with_each_rows_own_error():
    """With ``noise_per_output`` each observation's variance carries its own output's σ_ε:
    the model's log density equals a hand-built Gaussian (exact likelihood)."""
    from numpyro.infer.util import log_density

    x, unit, emulator = toy_emulator(k=1, runs=30, rows=10)
    obs_rows = np.arange(10)
    groups = np.array([0, 1] * 5)
    rng = np.random.default_rng(3)
    y = rng.normal(size=10)
    settings = BayesSettings(noise_per_output=True, likelihood="exact")
    data = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(1), settings,
                          obs_outputs=groups)
    assert data.n_noise == 2
    point = {"z": np.array([0.3]), "log_discrepancy_std": np.log(0.2),
             "log_discrepancy_lengthscale": np.array([0.1]),
             "log_noise_std": np.log(np.array([0.05, 0.4]))}
    model = bayes.make_model(False, data.priors, False, n_noise=2)
    value, _ = log_density(model, (bayes.model_arrays(data),), {}, point)
    # the same by hand: emulator moments at θ, δ's kernel, each row's own noise, and the priors
    t = emulator.grid.inputs.from_normal(point["z"][None, :])[0]
    mean = emulator.grid.predict_mean(t[None, :])[0, obs_rows]
    cov = emulator.grid.predict_cov(t)[np.ix_(obs_rows, obs_rows)]
    xs = emulator.grid.x[obs_rows]
    d2 = ((xs[:, None, :] - xs[None, :, :]) ** 2).sum(-1)
    cov = cov + 0.2 ** 2 * np.exp(-0.5 * d2 / np.exp(0.1) ** 2) \
        + np.diag(np.array([0.05, 0.4])[groups] ** 2 + 1e-8)
    expected = stats.multivariate_normal(mean, cov).logpdf(y)
    priors = data.priors
    expected += stats.norm(0, 1).logpdf(0.3)
    expected += stats.norm(*priors["log_discrepancy_std"]).logpdf(np.log(0.2))
    expected += stats.norm(*priors["log_discrepancy_lengthscale"]).logpdf(0.1)
    expected += stats.norm(*priors["log_noise_std"]).logpdf(np.log([0.05, 0.4])).sum()
    assert float(value) == pytest.approx(expected, rel=1e-6)


def test_lowrank_likelihood_with_every_observation_inducing_is_the_exact_gaussian():
    """The low-rank likelihood keeps the emulator's variances (not its covariances) and
    replaces δ's kernel by its Nyström/FITC form; with the inducing inputs at the
    observations themselves that form is exact, so the log density equals a hand-built
    Gaussian with diagonal emulator variance (ARD length-scale, each row's own noise)."""
    from numpyro.infer.util import log_density

    x, unit, emulator = toy_emulator(k=1, runs=30, rows=10)
    obs_rows = np.arange(10)
    groups = np.array([0, 1] * 5)
    rng = np.random.default_rng(4)
    y = rng.normal(size=10)
    settings = BayesSettings(noise_per_output=True, likelihood="lowrank", ard=True,
                             inducing_points=10)
    data = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(1), settings,
                          obs_outputs=groups)
    assert data.lowrank
    point = {"z": np.array([-0.4]), "log_discrepancy_std": np.log(0.3),
             "log_discrepancy_lengthscale": np.array([-1.2]),
             "log_noise_std": np.log(np.array([0.05, 0.4]))}
    model = bayes.make_model(True, data.priors, True, n_noise=2)
    value, _ = log_density(model, (bayes.model_arrays(data),), {}, point)
    t = emulator.grid.inputs.from_normal(point["z"][None, :])[0]
    mean = emulator.grid.predict_mean(t[None, :])[0, obs_rows]
    variance = np.diag(emulator.grid.predict_cov(t))[obs_rows]
    xs = emulator.grid.x[obs_rows]
    d2 = ((xs[:, None, :] - xs[None, :, :]) ** 2).sum(-1)
    cov = np.diag(variance + np.array([0.05, 0.4])[groups] ** 2) \
        + 0.3 ** 2 * np.exp(-0.5 * d2 / np.exp(-1.2) ** 2)
    expected = stats.multivariate_normal(mean, cov).logpdf(y)
    priors = data.priors
    expected += stats.norm(0, 1).logpdf(-0.4)
    expected += stats.norm(*priors["log_discrepancy_std"]).logpdf(np.log(0.3))
    expected += stats.norm(*priors["log_discrepancy_lengthscale"]).logpdf(-1.2)
    expected += stats.norm(*priors["log_noise_std"]).logpdf(np.log([0.05, 0.4])).sum()
    assert float(value) == pytest.approx(expected, rel=1e-4)


def test_woodbury_terms_hand_written_gradient_is_the_exact_gradient():
    """log det(I + W Wᵀ) − uᵀ(I + W Wᵀ)⁻¹u, u = W s: value and gradient (both arguments)
    against JAX differentiating the dense expression."""
    import jax
    import jax.numpy as jnp

    rng = np.random.default_rng(8)
    w, s = rng.normal(size=(7, 20)) * 0.7, rng.normal(size=20)

    def dense(w, s):
        a = jnp.eye(7) + w @ w.T
        u = w @ s
        return jnp.linalg.slogdet(a)[1] - u @ jnp.linalg.solve(a, u)

    assert float(bayes.woodbury_terms(w, s)) == pytest.approx(float(dense(w, s)), rel=1e-10)
    got = jax.grad(bayes.woodbury_terms, argnums=(0, 1))(w, s)
    want = jax.grad(dense, argnums=(0, 1))(w, s)
    for g, e in zip(got, want):
        np.testing.assert_allclose(np.asarray(g), np.asarray(e), rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("likelihood", ["exact", "lowrank"])
def test_per_output_discrepancy_scales_each_outputs_rows_of_one_correlation(likelihood):
    """With ``discrepancy_per_output`` δ's covariance is ``S K S`` with ``S`` each row's own
    output's σ_δ (one correlation ``K``, one scale per output): the model's log density equals
    a hand-built Gaussian, for the exact likelihood and for the low-rank one with every
    observation inducing (where FITC is exact)."""
    from numpyro.infer.util import log_density

    x, unit, emulator = toy_emulator(k=1, runs=30, rows=10)
    obs_rows = np.arange(10)
    groups = np.array([0, 1] * 5)
    y = np.random.default_rng(5).normal(size=10)
    settings = BayesSettings(noise_per_output=True, discrepancy_per_output=True,
                             likelihood=likelihood, inducing_points=10)
    data = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(1), settings,
                          obs_outputs=groups)
    assert (data.n_discrepancy, data.n_noise) == (2, 2)
    sd_delta, sd_eps = np.array([0.01, 0.6]), np.array([0.05, 0.2])
    point = {"z": np.array([0.2]), "log_discrepancy_std": np.log(sd_delta),
             "log_discrepancy_lengthscale": np.array([-0.5]), "log_noise_std": np.log(sd_eps)}
    lowrank = likelihood == "lowrank"
    model = bayes.make_model(False, data.priors, lowrank, n_noise=2, n_discrepancy=2)
    value, _ = log_density(model, (bayes.model_arrays(data),), {}, point)
    t = emulator.grid.inputs.from_normal(point["z"][None, :])[0]
    mean = emulator.grid.predict_mean(t[None, :])[0, obs_rows]
    cov = emulator.grid.predict_cov(t)[np.ix_(obs_rows, obs_rows)]
    if lowrank:
        cov = np.diag(np.diag(cov))
    xs = emulator.grid.x[obs_rows]
    d2 = ((xs[:, None, :] - xs[None, :, :]) ** 2).sum(-1)
    scale = sd_delta[groups]
    cov = cov + np.outer(scale, scale) * np.exp(-0.5 * d2 / np.exp(-0.5) ** 2) \
        + np.diag(sd_eps[groups] ** 2 + 1e-8)
    expected = stats.multivariate_normal(mean, cov).logpdf(y)
    priors = data.priors
    expected += stats.norm(0, 1).logpdf(0.2)
    expected += stats.norm(*priors["log_discrepancy_std"]).logpdf(np.log(sd_delta)).sum()
    expected += stats.norm(*priors["log_discrepancy_lengthscale"]).logpdf(-0.5)
    expected += stats.norm(*priors["log_noise_std"]).logpdf(np.log(sd_eps)).sum()
    assert float(value) == pytest.approx(expected, rel=1e-4)
    # a shared σ_δ (the default) is a different density at the same point
    shared = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(1),
                            settings.model_copy(update={"discrepancy_per_output": False}),
                            obs_outputs=groups)
    assert shared.n_discrepancy == 1


def test_predictive_discrepancy_takes_each_rows_own_output_scale():
    """In the posterior predictive, δ of an output whose σ_δ is near zero is near zero, while
    the other output's δ carries the residual; one shared scale would give both the same."""
    x, unit, emulator = toy_emulator(k=1, runs=30, rows=12)
    groups = np.array([0, 1] * 6)
    obs_rows, target_rows = np.arange(8), np.arange(8, 12)
    y = emulator.grid.predict_mean(emulator.grid.t_of_unit(np.array([[0.5]])))[0, obs_rows] + 0.4
    prediction = bayes.predictive(
        emulator.grid, obs_rows, target_rows, y, np.array([[0.5]]),
        log_sd_delta=np.log(np.array([[1e-4, 0.5]])), log_lengthscale=np.array([[0.5]]),
        log_sd_eps=np.log(np.array([[0.05, 0.05]])), ard=False, noise_index=groups)
    delta = prediction.discrepancy[0]
    assert np.all(np.abs(delta[groups[target_rows] == 0]) < 1e-3)
    assert np.all(delta[groups[target_rows] == 1] > 0.1)


@pytest.mark.parametrize("likelihood", ["exact", "lowrank"])
def test_known_correlated_error_is_the_gaussian_with_its_covariance_added(likelihood):
    """A known error with covariance ``F Fᵀ`` (the emulator's hold-out errors, correlated over
    rows) enters the log density as that covariance: equal to a hand-built Gaussian in the
    exact likelihood and in the low-rank one (Woodbury on δ's inducing inputs and F together);
    without it the density is the Gaussian without it."""
    from numpyro.infer.util import log_density

    x, unit, emulator = toy_emulator(k=1, runs=30, rows=10)
    obs_rows = np.arange(10)
    rng = np.random.default_rng(8)
    factor = 0.3 * rng.normal(size=(10, 3))
    y = factor[:, 0] * 3.0 + 0.05 * rng.normal(size=10)
    settings = BayesSettings(likelihood=likelihood, inducing_points=10)
    point = {"z": np.array([0.2]), "log_discrepancy_std": np.log(0.1),
             "log_discrepancy_lengthscale": np.array([-0.5]), "log_noise_std": np.log(0.05)}
    model = bayes.make_model(False, bayes.koh_data(emulator.grid, obs_rows, y, np.arange(1),
                                                   settings).priors, likelihood == "lowrank")

    def density(extra_factor):
        data = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(1), settings,
                              extra_factor=extra_factor)
        return float(log_density(model, (bayes.model_arrays(data),), {}, point)[0])

    t = emulator.grid.inputs.from_normal(point["z"][None, :])[0]
    mean = emulator.grid.predict_mean(t[None, :])[0, obs_rows]
    cov = emulator.grid.predict_cov(t)[np.ix_(obs_rows, obs_rows)]
    if likelihood == "lowrank":
        cov = np.diag(np.diag(cov))
    xs = emulator.grid.x[obs_rows]
    d2 = ((xs[:, None, :] - xs[None, :, :]) ** 2).sum(-1)
    cov = cov + 0.01 * np.exp(-0.5 * d2 / np.exp(-0.5) ** 2) + np.diag(np.full(10, 0.0025 + 1e-8))
    priors = bayes.koh_data(emulator.grid, obs_rows, y, np.arange(1), settings).priors
    prior_terms = (stats.norm(0, 1).logpdf(0.2)
                   + stats.norm(*priors["log_discrepancy_std"]).logpdf(np.log(0.1))
                   + stats.norm(*priors["log_discrepancy_lengthscale"]).logpdf(-0.5)
                   + stats.norm(*priors["log_noise_std"]).logpdf(np.log(0.05)))
    with_factor = stats.multivariate_normal(mean, cov + factor @ factor.T).logpdf(y)
    assert density(factor) == pytest.approx(with_factor + prior_terms, rel=1e-4)
    without = stats.multivariate_normal(mean, cov).logpdf(y)
    assert density(None) == pytest.approx(without + prior_terms, rel=1e-4)


def test_every_scenario_is_checked_before_the_design_runs(tmp_path):
    """A scenario output no test reports, one the measured file lacks, or one listed twice
    is refused before any simulation (they once failed after the previous scenario's NUTS,
    or counted every observation twice)."""
    config, measured, _ = _short_calibration_config(tmp_path, scenarios=True)
    raw = yaml.safe_load(config.read_text())

    def calibrate_with(scenario: dict, measured_file: Path = measured) -> str:
        raw["calibration"]["scenarios"] = [raw["calibration"]["scenarios"][0], scenario]
        (tmp_path / "changed").mkdir(exist_ok=True)
        changed = write_config(tmp_path / "changed", raw)
        result = CliRunner().invoke(app, ["calibrate", str(changed), "--measured",
                                          str(measured_file), "--scenarios", "--no-progress"])
        assert result.exit_code == 2, result.output
        assert not (tmp_path / "changed" / "run" / "calibration").exists()
        return " ".join(result.output.split())

    untested = calibrate_with({"name": "D-C", "outputs": ["heating_power_w", "cooling_power_w"]})
    assert "calibration.scenarios (D-C).outputs[1]" in untested and "not an output of any test" in untested
    twice = calibrate_with({"name": "D-H", "outputs": ["heating_power_w", "heating_power_w"]})
    assert "heating_power_w listed more than once" in twice
    frame = pd.read_csv(measured)
    without = tmp_path / "no_temperature.csv"
    frame.drop(columns=["zone_air_temperature_c"]).to_csv(without, index=False)
    lacking = calibrate_with({"name": "D-ET", "outputs": ["heating_power_w",
                                                         "zone_air_temperature_c"]}, without)
    assert "no_temperature.csv" in lacking and "zone_air_temperature_c" in lacking


def test_outputs_of_tests_before_the_held_out_days_and_a_single_held_out_day(tmp_path):
    """Two tests, the heating one ending before the held-out day: the physical check scores
    what the held-out day holds (it once failed after all the work, naming the heating output
    as reported by no test), and one held-out day gives no (n - 1) metric, not an error."""
    config, measured, _ = _short_calibration_config(tmp_path)
    raw = yaml.safe_load(config.read_text())
    raw["model"]["tests"] = [
        {"name": "H", "period": "cal", "start": "11-08", "days": 8, "warmup_days": 2,
         "mode": "heating", "setpoint_c": 30.0, "setback_c": 24.0,
         "outputs": ["heating_power_w"]},
        {"name": "F", "period": "cal", "start": "11-16", "days": 4, "warmup_days": 1,
         "mode": "free_floating", "outputs": ["zone_air_temperature_c"]}]
    raw["calibration"].update(outputs=["heating_power_w", "zone_air_temperature_c"],
                              holdout_days=1)
    (tmp_path / "two").mkdir()
    two = write_config(tmp_path / "two", raw)
    truth = tmp_path / "truth2.yaml"
    truth.write_text("seed: 1\nvalues: {glazing_dirt_correction: 0.9}\n")
    runner = CliRunner()
    result = runner.invoke(app, ["synth", str(two), "--truth", str(truth)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["calibrate", str(two), "--measured",
                                 str(tmp_path / "two" / "run" / "truth" / "measured.csv"),
                                 "--method", "deterministic", "--no-progress"])
    assert result.exit_code == 0, result.output
    flat = " ".join(result.output.split())
    assert "no held-out days of heating_power_w" in flat
    record = json.loads((tmp_path / "two" / "run" / "calibration" / "calibration.json")
                        .read_text())
    rows = [r for r in record["heldout"] if r["model"] == "deterministic_physical"]
    assert {r["output"] for r in rows} == {"zone_air_temperature_c"}
    daily = next(r for r in rows if r["resolution"] == "daily")
    assert daily["n"] == 1 and daily["rmse"] is None and daily["mcrps"] is not None
    hourly = next(r for r in rows if r["resolution"] == "hourly")
    assert hourly["n"] == 24 and hourly["rmse"] > 0


def test_hold_out_and_data_gaps_are_refused_before_the_design_runs(tmp_path):
    """Found after every design run had finished: a hold-out leaving one daily value, and a
    measured file that stops early."""
    config, measured, _ = _short_calibration_config(tmp_path)
    raw = yaml.safe_load(config.read_text())
    raw["calibration"]["holdout_days"] = 9               # 10 evaluated days: 1 left
    (tmp_path / "long").mkdir()
    long_holdout = write_config(tmp_path / "long", raw)
    runner = CliRunner()
    result = runner.invoke(app, ["calibrate", str(long_holdout), "--measured", str(measured),
                                 "--method", "deterministic", "--no-progress"])
    flat = " ".join(result.output.split())
    assert result.exit_code == 2 and "calibration.holdout_days" in flat
    assert "1 daily calibration value(s)" in flat
    assert not (tmp_path / "long" / "run" / "calibration" / "design").exists()
    short = pd.read_csv(measured).iloc[:-30]
    short.to_csv(tmp_path / "short.csv", index=False)
    result = runner.invoke(app, ["calibrate", str(config), "--measured",
                                 str(tmp_path / "short.csv"), "--method", "deterministic",
                                 "--no-progress"])
    assert result.exit_code == 2 and "the measured data cover" in " ".join(result.output.split())
    assert not (tmp_path / "run" / "calibration" / "design").exists()


@pytest.mark.slow
def test_a_calibration_into_the_folder_of_another_moves_that_one_aside(tmp_path):
    config, measured, _ = _short_calibration_config(tmp_path)
    out = tmp_path / "out"
    runner = CliRunner()
    for _ in range(2):
        result = runner.invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                     "--method", "deterministic", "--out", str(out),
                                     "--no-progress"])
        assert result.exit_code == 0, result.output
    assert "earlier calibration" in " ".join(result.output.split())
    earlier = list((out / "previous").glob("*"))
    assert len(earlier) == 1 and (earlier[0] / "calibration.json").is_file()
    assert (earlier[0] / "figures").is_dir() and (out / "calibration.json").is_file()


@pytest.mark.slow
def test_a_failed_scenario_leaves_a_comparison_of_the_finished_ones(tmp_path, monkeypatch):
    from bpsflow.calibration import workflow

    config, measured, _ = _short_calibration_config(tmp_path, scenarios=True)
    out = tmp_path / "run" / "calibration"
    (out).mkdir(parents=True)
    stale = "scenario,outputs\nOLD,heating_power_w\n"
    (out / "scenarios.csv").write_text(stale)
    real = workflow.calibrate_scenario

    def second_fails(config, settings, scenario, *args, **kwargs):
        if scenario.name == "D-ET":
            raise BpsflowError("calibration.scenarios (D-ET): made to fail")
        return real(config, settings, scenario, *args, **kwargs)

    monkeypatch.setattr(workflow, "calibrate_scenario", second_fails)
    result = CliRunner().invoke(app, ["calibrate", str(config), "--measured", str(measured),
                                      "--scenarios", "--method", "deterministic",
                                      "--no-progress"])
    assert result.exit_code != 0
    said = " ".join(result.output.split())
    assert "scenario D-ET failed" in said and "compares only the scenarios calibrated now (D-E)" \
        in said and "D-ET were not calibrated again" in said, said
    table = pd.read_csv(out / "scenarios.csv")
    assert list(table["scenario"]) == ["D-E"]


@pytest.mark.slow
def test_a_deterministic_optimum_at_its_priors_end_is_said(tmp_path):
    """The truth (0.9) lies below this prior (0.97-1.0): the optimum can only sit at its end."""
    config, measured, _ = _short_calibration_config(tmp_path)
    raw = yaml.safe_load(config.read_text())
    glazing = next(p for p in raw["parameters"] if p["name"] == "glazing_dirt_correction")
    glazing["distribution"] = {"type": "uniform", "lower": 0.97, "upper": 1.0}
    narrow = tmp_path / "narrow.yaml"
    narrow.write_text(yaml.safe_dump(raw))
    result = CliRunner().invoke(app, ["calibrate", str(narrow), "--measured", str(measured),
                                      "--method", "deterministic", "--out",
                                      str(tmp_path / "det"), "--no-progress"])
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())
    assert "deterministic optimum sits at its prior's end for glazing_dirt_correction (lower " \
        "end)" in said, said
    record = json.loads((tmp_path / "det" / "calibration.json").read_text())
    at_bound = {p["name"]: p["deterministic_at_bound"] for p in record["parameters"]}
    # (the other input may be pushed to an end as well, compensating: not asserted)
    assert at_bound["glazing_dirt_correction"] == "lower"


def test_a_truth_without_some_calibration_parameters_says_so(tmp_path, monkeypatch):
    """A truth of another run once reported '5 of 5 covered' with a sixth parameter unjudged."""
    from bpsflow.calibration import workflow
    from bpsflow.config import Parameter
    from bpsflow.distributions import Uniform

    def parameter(name: str) -> Parameter:
        return Parameter(name=name, mode="absolute",
                         distribution=Uniform(type="uniform", lower=0.0, upper=1.0),
                         targets=[{"object": "Material", "name": "x", "field": "Thickness"}])

    import io

    from rich.console import Console

    printed = io.StringIO()
    monkeypatch.setattr(workflow, "console", Console(file=printed, width=200))
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"values": {"a": 0.5}}))
    values = workflow.read_truth(truth, [parameter("a"), parameter("b")])
    assert values == {"a": 0.5}
    said = " ".join(printed.getvalue().split())
    assert "no true value of calibration parameter(s) b; their coverage is not judged" in said


def test_no_nuts_progress_bar_off_a_terminal():
    """tqdm's bar wrote a stream of carriage returns into log files (120 kB for one run)."""
    settings = BayesSettings(chains=1, warmup=1, samples=1)
    mcmc = bayes._mcmc(False, (("log_discrepancy_std", (0.0, 1.0)),), False, settings,
                       "sequential", True, None)
    assert mcmc.progress_bar is False       # pytest's stderr is not a terminal
