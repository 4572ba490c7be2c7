"""The ``calibration:`` section of a config (validated with pydantic, no heavy imports).

Kennedy–O'Hagan calibration (seed §4.3, eq. 19–22) and the deterministic
baseline are driven by this section; ``configs/calibration.yaml`` is the
shipped example::

    calibration:
      outputs: [heating_power_w]          # which measured outputs to calibrate to
      resolution: daily                   # daily | hourly (seed Table 4.1)
      holdout_days: 7                     # the last days of the evaluated period
      design: {runs: 840, seed: 11}       # LHD over the calibration parameters
      scenarios:                          # bpsflow calibrate --scenarios
        - {name: D-E, outputs: [heating_power_w], resolution: daily}

Calibration parameters θ are the config's non-constant parameters (a
``constant`` distribution marks a parameter screened out and fixed), unless
``parameters`` names them; every other parameter is held at its nominal value
(its distribution's median) in every calibration run.

This module imports only pydantic so that :mod:`bpsflow.config` can use it
without loading JAX.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from bpsflow.names import SafeName
from bpsflow.schema import StrictModel

Resolution = Literal["daily", "hourly"]

#: Variable inputs x a calibration may use (seed Table 4.2, lower half). Weather
#: quantities are means over the interval (day or hour) from the config's EPW.
VARIABLE_INPUTS = (
    "outdoor_air_temperature",          # °C, interval mean
    "outdoor_air_temperature_24h",      # °C, mean of the 24 h before the interval
    "global_horizontal_radiation",      # W/m², interval mean
    "global_horizontal_radiation_24h",  # W/m², mean of the 24 h before the interval
    "direct_normal_radiation",          # W/m²
    "diffuse_horizontal_radiation",     # W/m²
    "wind_speed",                       # m/s
    "hour_of_day",                      # 0..23, hour the interval starts (hourly only)
    "hour_of_day_sin", "hour_of_day_cos",  # the hour on the unit circle (hourly only)
    "weekend",                          # 1 on Saturday and Sunday
    "setpoint_c",                       # °C, setpoint in force (interval mean)
    "setpoint_c_lag2",                  # °C, setpoint two hours before (seed Table 4.2 #6)
    "output",                           # output-type indicator (seed §4.3.3), when pooled
)

DEFAULT_VARIABLE_INPUTS: dict[str, list[str]] = {
    "daily": ["outdoor_air_temperature", "outdoor_air_temperature_24h",
              "global_horizontal_radiation", "wind_speed", "output"],
    "hourly": ["outdoor_air_temperature", "outdoor_air_temperature_24h",
               "global_horizontal_radiation", "global_horizontal_radiation_24h", "wind_speed",
               "hour_of_day_sin", "hour_of_day_cos", "setpoint_c", "setpoint_c_lag2", "output"],
}


class _Strict(StrictModel):
    pass


class CalibrationDesign(_Strict):
    """The Latin hypercube over θ whose runs train the emulator (seed §4.3.4: 840 points)."""

    runs: int = Field(default=840, ge=10, le=100_000)
    seed: int = 0


class ScreenedErrorSettings(_Strict):
    """The spread of the inputs screening fixed, as known error in the likelihood.

    With ``runs`` > 0 the calibration runs ``runs`` simulations (plus one with
    every input nominal): θ at its prior median, each input screening fixed
    drawn (Latin hypercube, ``seed``) from the distribution it had before
    (``provenance.original_distribution``, written by ``bpsflow sensitivity
    --screen``). Their deviations from the nominal run enter the likelihood
    as a known correlated error (:mod:`bpsflow.calibration.known_error`).
    0 (default): screened-out inputs are taken as known at their medians.
    """

    runs: int = Field(default=0, ge=0, le=10_000)
    seed: int = 0

    @model_validator(mode="after")
    def _check(self) -> ScreenedErrorSettings:
        if 0 < self.runs < 5:
            raise ValueError(f"runs: {self.runs} runs cannot measure a spread; use 0 (off) "
                             "or at least 5 (40 resolve an hourly floor's)")
        return self


class RefinementSettings(_Strict):
    """Design runs added where the posterior lies, and the posterior sampled again.

    With ``runs`` > 0 a Bayesian calibration, once sampled, runs the model at
    ``runs`` posterior draws of θ (spread over the draws, ``seed``) over the
    design's period, adds them to the design runs, refits the emulator and
    samples the posterior again from its new moments: the emulator is then
    densest where the posterior is, which is where its error biases θ
    (sequential design; seed §2.3 on the emulator's accuracy, Santner et al.
    2018, ch. 6). ``rounds`` repeats this. 0 (default): the first posterior
    is the answer.
    """

    runs: int = Field(default=0, ge=0, le=10_000)
    rounds: int = Field(default=1, ge=1, le=5)
    seed: int = 0

    @model_validator(mode="after")
    def _check(self) -> RefinementSettings:
        if 0 < self.runs < 10:
            raise ValueError(f"runs: {self.runs} runs are too few to move the emulator; use 0 "
                             "(off) or at least 10")
        return self


class EmulatorSettings(_Strict):
    """GP emulator of η(x, t) (seed eq. 20): ARD squared exponential, MLE hyperparameters.

    ``points`` (run, time) pairs are drawn from the training runs for the
    maximum-likelihood fit of the hyperparameters; ``test_fraction`` of the
    runs are held out to test the emulator (seed: 10 %).

    ``inputs`` is how the calibration parameters enter the kernel: ``value``
    (default), each parameter's value standardised by its prior mean and
    standard deviation; ``unit``, its prior CDF value (uniform). Outputs are
    smooth in the physical value; through the CDF a lognormal input's effect
    bends sharply in its tail, which a stationary kernel follows only with
    short length-scales everywhere. Priors with steps (discrete, empirical)
    always enter as ``unit``.

    ``hyperparameters`` is ``per_output`` (default): each output is its own
    GP with its own length-scales, fitted on its own ``points``; or
    ``shared``: one GP over every output, the output type a variable input.
    Heating can want short length-scales on a leakage area where electricity
    wants long ones on everything but its loads; a shared kernel compromises.

    ``fit`` is ``points`` (default): the hyperparameters of the scattered-
    point fit; or ``grid``: that fit refined on the whole grid of training
    runs × rows, with a row term: each row's own response to θ, shared by the
    runs (an hour's heating depends on the building's thermal history, which
    its variable inputs do not carry). ``grid`` makes the emulator more
    accurate on its held-out runs; the posterior then narrows, and where the
    model has a form error that the discrepancy does not absorb, its intervals
    cover the truth less often (see README).
    """

    points: int = Field(default=840, ge=20)
    fit: Literal["points", "grid"] = "points"
    inputs: Literal["value", "unit"] = "value"
    hyperparameters: Literal["per_output", "shared"] = "per_output"
    test_fraction: float = Field(default=0.1, ge=0.0, lt=0.5)
    restarts: int = Field(default=0, ge=0)
    seed: int = 0


class LogNormalPrior(_Strict):
    """A lognormal prior given by its median and the standard deviation of its log."""

    median: float = Field(gt=0)
    log_sd: float = Field(default=0.5, gt=0)


class BayesSettings(_Strict):
    """NUTS over θ, δ's hyperparameters and σ_ε (seed eq. 21–22).

    Priors on δ and ε are in standardised output units (each output divided
    by its standard deviation over the simulations): the seed assumes about
    20 % model bias and 5 % observation error (§4.3.5, after Guillas et al.
    2009). ``discrepancy_lengthscale`` is on the standardised variable inputs;
    ``ard: true`` gives δ one length-scale per variable input instead of one
    shared.

    A run is converged when every sampled quantity has split R-hat (rank
    normalised) at most ``rhat_max``, bulk and tail ESS at least ``ess_min``
    and the share of divergent transitions is at most ``divergence_max``.

    Chains start around the posterior mode, found from the deterministic
    optimum (``init: deterministic``) or the prior medians (``prior``); with
    ``laplace: true`` the starts are drawn from the Laplace approximation
    (widened 1.5 times, so R-hat compares dispersed chains) and its covariance
    is the initial dense mass matrix.

    ``noise_per_output: true`` gives each pooled output its own observation
    error σ_ε (same prior): outputs measured by different instruments (a
    meter read in coarse steps beside a fine one) otherwise share one σ_ε
    that the most precise output pulls down, and the others' residuals are
    then explained by θ.

    ``discrepancy_per_output: true`` gives each pooled output its own δ
    scale σ_δ (same prior) on δ's shared correlation: a meter the model
    reproduces closely (electricity summed from load densities) otherwise
    pulls the one σ_δ towards zero, and the other outputs' model-form error is
    then read as white noise, which pins θ far too tightly at hourly
    resolution.

    ``emulator_error: holdout`` adds the emulator's mean squared error on the
    held-out runs (per output, standardised) to every observation's variance:
    the GP's own conditional variance is far smaller than its error on new
    runs, and without this the calibration parameters absorb the emulator's
    error and their posterior is too narrow. ``correlated`` adds the held-out
    runs' errors with their correlation between rows instead (covariance
    ``F Fᵀ + diag(v)``: the leading singular directions of the runs' errors,
    holding 99 % of their second moment, and the rest of each row's squared
    error on the diagonal): at a given θ the emulator errs alike over many
    hourly rows, which per-row variances average away.

    Chains run ``parallel_chains`` at a time (default: all of them for up to
    30 observations, else one after another, each using every core).

    ``likelihood``: ``exact`` is the Gaussian likelihood of the observations
    given the simulations with full covariances (one ``n × n`` Cholesky per
    step); ``lowrank`` replaces δ's covariance by its FITC approximation on
    ``inducing_points`` k-means inputs and keeps only the emulator's variances
    (its covariances between observations are orders of magnitude under the
    noise), ``O(n m²)`` per step; ``auto`` is exact up to
    ``exact_max_observations`` observations.

    ``extend``: while the draws miss ``rhat_max`` or ``ess_min`` (and
    divergences are within ``divergence_max``), every chain draws ``samples``
    more from where it stopped, up to ``extend`` times; warm-up is not
    repeated. The report gives the draws per chain that convergence took.

    ``screen_effect`` drops from the sampler the calibration parameters whose
    largest effect on the emulator over their range is under this many
    standardised output units: the data cannot inform them, so their
    posterior is their prior (reported as such).
    """

    chains: int = Field(default=4, ge=1, le=64)
    warmup: int = Field(default=500, ge=0, le=1_000_000)
    samples: int = Field(default=1000, ge=1, le=1_000_000)
    target_accept: float = Field(default=0.85, gt=0, lt=1)
    max_tree_depth: int = Field(default=8, ge=1, le=15)
    dense_mass: bool = True
    chain_method: Literal["auto", "parallel", "vectorized", "sequential"] = "auto"
    parallel_chains: int | None = Field(default=None, ge=1)
    seed: int = 0
    init: Literal["deterministic", "prior"] = "deterministic"
    laplace: bool = True
    discrepancy_std: LogNormalPrior = Field(default_factory=lambda: LogNormalPrior(median=0.2))
    discrepancy_lengthscale: LogNormalPrior = Field(
        default_factory=lambda: LogNormalPrior(median=1.0, log_sd=0.75))
    noise_std: LogNormalPrior = Field(default_factory=lambda: LogNormalPrior(median=0.05))
    ard: bool = False
    noise_per_output: bool = False
    discrepancy_per_output: bool = False
    emulator_error: Literal["holdout", "correlated", "none"] = "holdout"
    likelihood: Literal["auto", "exact", "lowrank"] = "auto"
    exact_max_observations: int = Field(default=150, ge=1)
    inducing_points: int = Field(default=32, ge=4)
    screen_effect: float = Field(default=0.01, ge=0)
    rhat_max: float = Field(default=1.01, gt=1)
    extend: int = Field(default=0, ge=0, le=10)
    ess_min: float = Field(default=400, ge=0)
    divergence_max: float = Field(default=0.01, ge=0, le=1)


class DeterministicSettings(_Strict):
    """Bounded multi-start minimisation of w₁·NMBE² + w₂·CV(RMSE)² (seed §4.3.5, Reddy 2007).

    ``model: emulator`` minimises over the emulator's mean (any backend,
    cheap); ``simulator`` over the physical model itself (surrogate backend
    only: each objective evaluation is a simulation).
    """

    nmbe_weight: float = Field(default=1.0, ge=0)
    cv_rmse_weight: float = Field(default=1.0, ge=0)
    starts: int = Field(default=8, ge=1)
    seed: int = 0
    model: Literal["emulator", "simulator"] = "emulator"

    @model_validator(mode="after")
    def _weights(self) -> DeterministicSettings:
        if self.nmbe_weight + self.cv_rmse_weight <= 0:
            raise ValueError("nmbe_weight and cv_rmse_weight cannot both be 0")
        return self


class Scenario(_Strict):
    """One data scenario (seed Table 4.1): which outputs, at which resolution."""

    name: SafeName
    outputs: list[str] = Field(min_length=1)
    resolution: Resolution = "daily"
    variable_inputs: list[str] | None = None

    @model_validator(mode="after")
    def _distinct_outputs(self) -> Scenario:
        repeated = sorted({o for o in self.outputs if self.outputs.count(o) > 1})
        if repeated:
            # each observation would count twice and the posterior be too narrow
            raise ValueError(f"outputs: {', '.join(repeated)} listed more than once")
        return self


class CalibrationSettings(_Strict):
    """The ``calibration:`` section. See the module docstring for an example.

    ``max_observations`` caps the calibration observations (a seeded random
    subset is kept, recorded in ``calibration.json``); the seed keeps one
    hourly output per sample point for the same reason (§4.3.4).
    ``idle_fraction``: hourly and daily heating/cooling observations at or
    below this fraction of the output's mean are dropped (the system was off;
    seed §4.3.4 drops hourly heating outputs when heating is off).
    ``posterior_runs``: posterior draws re-run on the physical model over the
    held-out period (seed: 100).
    """

    parameters: list[str] | None = None
    outputs: list[str] | None = None
    resolution: Resolution = "daily"
    variable_inputs: list[str] | None = None
    holdout_days: int = Field(default=7, ge=1)
    max_observations: int = Field(default=300, ge=5)
    observation_seed: int = 0
    idle_fraction: float = Field(default=0.01, ge=0, lt=1)
    design: CalibrationDesign = Field(default_factory=CalibrationDesign)
    emulator: EmulatorSettings = Field(default_factory=EmulatorSettings)
    screened_error: ScreenedErrorSettings = Field(default_factory=ScreenedErrorSettings)
    refinement: RefinementSettings = Field(default_factory=RefinementSettings)
    bayes: BayesSettings = Field(default_factory=BayesSettings)
    deterministic: DeterministicSettings = Field(default_factory=DeterministicSettings)
    posterior_runs: int = Field(default=100, ge=2)
    scenarios: list[Scenario] = Field(default_factory=list)

    @model_validator(mode="after")
    def _check(self) -> CalibrationSettings:
        for key in ("outputs", "parameters"):
            listed = getattr(self, key)
            if listed == []:
                raise ValueError(f"{key}: the list is empty; name at least one (or leave the "
                                 f"key out for the default)")
            repeated = sorted({o for o in listed or [] if listed.count(o) > 1})
            if repeated:
                # each observation would count twice and the posterior be too narrow
                raise ValueError(f"{key}: {', '.join(repeated)} listed more than once")
        if self.emulator.test_fraction == 0 and self.bayes.emulator_error != "none":
            # the emulator's error term is measured on its held-out runs: none, no term
            raise ValueError(f"emulator.test_fraction: 0 holds out no design runs, and "
                             f"bayes.emulator_error: {self.bayes.emulator_error} measures the "
                             f"emulator's error on them; expected a fraction above 0 (e.g. "
                             f"0.1), or bayes.emulator_error: none")
        names = [s.name for s in self.scenarios]
        if len(set(names)) != len(names):
            repeated = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"scenarios: scenario names must be unique ({', '.join(repeated)} "
                             "repeated)")
        for where, inputs in [("variable_inputs", self.variable_inputs)] + [
                (f"scenarios ({s.name}).variable_inputs", s.variable_inputs)
                for s in self.scenarios]:
            if inputs == []:
                # an empty list read as 'the default inputs': refused, not ignored
                raise ValueError(f"{where}: the list is empty; name at least one of "
                                 f"{', '.join(VARIABLE_INPUTS)} (or leave the key out for the "
                                 f"default)")
            for name in inputs or []:
                if name not in VARIABLE_INPUTS:
                    raise ValueError(f"{where}: unknown variable input '{name}', expected some "
                                     f"of {', '.join(VARIABLE_INPUTS)}")
        return self

    def scenario(self, default_outputs: list[str]) -> Scenario:
        """The top-level choice of outputs and resolution as a scenario named ``main``."""
        return Scenario(name="main", outputs=self.outputs or default_outputs,
                        resolution=self.resolution, variable_inputs=self.variable_inputs)
