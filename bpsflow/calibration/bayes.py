"""Kennedy–O'Hagan calibration in NumPyro: the model, NUTS, convergence diagnostics.

The field observations (standardised) are ``y = η(x, θ) + δ(x) + ε``
(seed eq. 19). With the emulator's hyperparameters fixed (modular MLE), the
joint likelihood of simulations and observations (seed eq. 22) is the
likelihood of the simulations — a constant — times that of the observations
*conditioned on the simulations*:

    y | y_sim, θ, φ_δ ~ N( m(θ),  C_η(θ) + σ_δ² K_δ(x; ℓ_δ) + σ_ε² I ),

with ``m`` and ``C_η`` the emulator's conditional mean and covariance at
``(x_obs, θ)`` (:class:`bpsflow.calibration.emulator.GridEmulator`: the
simulator block is factorised once; each step costs an ``n_obs × n_obs``
Cholesky). The posterior is seed eq. 21.

Parametrisation (the geometry NUTS sees):

* θ is non-centred through its prior's CDF: ``z ~ N(0, 1)``,
  ``u = Φ(z)``, ``θ = F⁻¹(u)``, so every calibration parameter has a
  standard normal prior whatever its distribution (the emulator takes
  ``u``).
* δ's standard deviation and length-scale(s) and σ_ε are sampled on the log
  scale with normal priors (lognormal priors: median and log-sd from the
  config; seed §4.3.5: ~20 % model bias, ~5 % observation error, in
  standardised output units).
* a dense mass matrix is adapted in warm-up; chains start around the
  deterministic optimum (jittered, so R-hat still compares dispersed starts);
  calibration parameters whose effect on the emulator is negligible are not
  sampled — their posterior is their prior.

Diagnostics follow Vehtari et al. (2021): rank-normalised split R-hat (the
larger of bulk and folded), bulk ESS (rank-normalised) and tail ESS (the 5 %
and 95 % quantile indicators), computed with :mod:`numpyro.diagnostics`.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import special, stats

from bpsflow.calibration.emulator import SQRT12, GridEmulator
from bpsflow.calibration.settings import BayesSettings

SITES = ("z", "log_discrepancy_std", "log_discrepancy_lengthscale", "log_noise_std")
_JITTER = 1e-8


def configure_jax(devices: int) -> None:
    """Ask XLA for ``devices`` CPU devices (parallel chains) and float64; call before JAX runs.

    The device count only takes effect if no JAX computation has run in the
    process yet; otherwise chains run one after another (still correct).
    """
    import numpyro

    devices = max(1, int(devices))
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        numpyro.set_host_device_count(devices)
    numpyro.enable_x64()


@dataclass
class KohData:
    """Everything the likelihood needs, as arrays (standardised units).

    ``active`` lists the sampled calibration parameters (indices into θ);
    the others sit at their prior median in the emulator.
    """

    y: np.ndarray                  # (n,) standardised observations
    ux_obs: np.ndarray             # (n, B) rows of U_x at the observations
    mean_weights: np.ndarray       # (R, B)
    t_vectors: np.ndarray          # (R, R)
    inverse_d: np.ndarray          # (R, B)
    x_values: np.ndarray           # (B,)
    signal_variance: float
    t_scaled: np.ndarray           # (R, k_active) runs' t / ℓ_t
    inverse_lengthscales: np.ndarray  # (k_active,)
    log_base: np.ndarray           # (R,) log k_t over the screened-out parameters
    x_obs: np.ndarray              # (n, d_x) standardised variable inputs
    active: np.ndarray             # (k_active,) indices of sampled parameters
    n_parameters: int
    ard: bool
    priors: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (mean, sd) of log


def koh_data(grid: GridEmulator, obs_rows: np.ndarray, y: np.ndarray, active: np.ndarray,
             settings: BayesSettings) -> KohData:
    """Assemble the likelihood's arrays from the emulator and the observation rows."""
    active = np.asarray(active, dtype=int)
    screened = np.setdiff1d(np.arange(grid.t.shape[1]), active)
    lengthscales = grid.hyper.t_lengthscales
    log_base = -0.5 * np.sum((grid.t[:, screened] / lengthscales[screened]) ** 2, axis=1)
    priors = {
        "log_discrepancy_std": (np.log(settings.discrepancy_std.median),
                                settings.discrepancy_std.log_sd),
        "log_discrepancy_lengthscale": (np.log(settings.discrepancy_lengthscale.median),
                                        settings.discrepancy_lengthscale.log_sd),
        "log_noise_std": (np.log(settings.noise_std.median), settings.noise_std.log_sd),
    }
    return KohData(y=np.asarray(y, float), ux_obs=grid.x_vectors[obs_rows],
                   mean_weights=grid.mean_weights, t_vectors=grid.t_vectors,
                   inverse_d=grid.inverse_d, x_values=grid.x_values,
                   signal_variance=grid.hyper.signal_variance,
                   t_scaled=grid.t[:, active] / lengthscales[active],
                   inverse_lengthscales=1.0 / lengthscales[active], log_base=log_base,
                   x_obs=grid.x[obs_rows], active=active, n_parameters=grid.t.shape[1],
                   ard=settings.ard, priors=priors)


def _emulator_moments(z, d: dict):
    """Emulator mean and covariance at the observations for non-centred θ ``z`` (JAX)."""
    import jax.numpy as jnp
    from jax.scipy.special import ndtr

    t = (ndtr(z) - 0.5) * SQRT12 * d["inverse_lengthscales"]
    log_w = d["log_base"] - 0.5 * jnp.sum((t[None, :] - d["t_scaled"]) ** 2, axis=1)
    v = d["t_vectors"].T @ jnp.exp(log_w)
    mean = d["ux_obs"] @ (d["mean_weights"].T @ v)
    s2, mu = d["signal_variance"], d["x_values"]
    c = jnp.clip(s2 * mu - s2 * s2 * mu * mu * (d["inverse_d"].T @ (v * v)), 0.0, None)
    cov = (d["ux_obs"] * c) @ d["ux_obs"].T
    return mean, cov


def _discrepancy_kernel(log_lengthscale, d: dict, ard: bool):
    import jax.numpy as jnp

    if ard:
        scaled = d["x_obs"] * jnp.exp(-log_lengthscale)
        sq = jnp.sum(scaled * scaled, axis=1)
        d2 = sq[:, None] + sq[None, :] - 2.0 * scaled @ scaled.T
    else:
        d2 = d["x_sqdist"] * jnp.exp(-2.0 * log_lengthscale[0])
    return jnp.exp(-0.5 * jnp.maximum(d2, 0.0))


def gaussian_log_density(cov, residual):
    """``log N(residual; 0, cov)`` with a hand-written gradient (JAX).

    The gradient ``∂/∂cov = ½ (α αᵀ − cov⁻¹)``, ``α = cov⁻¹ residual``, from
    one Cholesky factor costs about half of differentiating through the
    factorisation and the triangular solve.
    """
    return _gaussian_log_density()(cov, residual)


def _gaussian_log_density():
    import jax
    import jax.numpy as jnp
    from jax.scipy.linalg import cho_solve, solve_triangular

    global _GAUSSIAN
    if _GAUSSIAN is not None:
        return _GAUSSIAN

    def value(chol, alpha, residual):
        n = residual.shape[0]
        return (-0.5 * residual @ alpha - jnp.sum(jnp.log(jnp.diag(chol)))
                - 0.5 * n * jnp.log(2 * jnp.pi))

    @jax.custom_vjp
    def density(cov, residual):
        chol = jnp.linalg.cholesky(cov)
        return value(chol, cho_solve((chol, True), residual), residual)

    def forward(cov, residual):
        chol = jnp.linalg.cholesky(cov)
        alpha = cho_solve((chol, True), residual)
        return value(chol, alpha, residual), (chol, alpha)

    def backward(saved, g):
        chol, alpha = saved
        inverse_chol = solve_triangular(chol, jnp.eye(chol.shape[0]), lower=True)
        inverse = inverse_chol.T @ inverse_chol
        return g * 0.5 * (jnp.outer(alpha, alpha) - inverse), -g * alpha

    density.defvjp(forward, backward)
    _GAUSSIAN = density
    return density


_GAUSSIAN = None


def make_model(ard: bool, priors: dict[str, tuple[float, float]]):
    """The NumPyro model of seed eq. 19–22 (see the module docstring).

    ``ard`` and the priors are fixed in the closure; the arrays (the data and
    the factorised simulator block) are the model's argument, so JAX
    compiles once for any data of the same shape.
    """
    def koh_model(d: dict) -> None:
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        k = d["t_scaled"].shape[1]
        z = numpyro.sample("z", dist.Normal(0.0, 1.0).expand([k]).to_event(1))
        m, s = priors["log_discrepancy_std"]
        log_sd_delta = numpyro.sample("log_discrepancy_std", dist.Normal(m, s))
        m, s = priors["log_discrepancy_lengthscale"]
        n_ls = d["x_obs"].shape[1] if ard else 1
        log_ls = numpyro.sample("log_discrepancy_lengthscale",
                                dist.Normal(m, s).expand([n_ls]).to_event(1))
        m, s = priors["log_noise_std"]
        log_sd_eps = numpyro.sample("log_noise_std", dist.Normal(m, s))
        mean, cov = _emulator_moments(z, d)
        n = d["y"].shape[0]
        total = (cov + jnp.exp(2 * log_sd_delta) * _discrepancy_kernel(log_ls, d, ard)
                 + (jnp.exp(2 * log_sd_eps) + _JITTER) * jnp.eye(n))
        numpyro.factor("y", gaussian_log_density(total, d["y"] - mean))

    return koh_model


def model_arrays(data: KohData) -> dict:
    """The JAX-side arrays of :class:`KohData` (pairwise distances precomputed)."""
    x = data.x_obs
    sq = np.sum(x * x, axis=1)
    x_sqdist = np.maximum(sq[:, None] + sq[None, :] - 2.0 * x @ x.T, 0.0)
    return {"y": data.y, "ux_obs": data.ux_obs, "mean_weights": data.mean_weights,
            "t_vectors": data.t_vectors, "inverse_d": data.inverse_d,
            "x_values": data.x_values, "signal_variance": np.float64(data.signal_variance),
            "t_scaled": data.t_scaled, "inverse_lengthscales": data.inverse_lengthscales,
            "log_base": data.log_base, "x_obs": x, "x_sqdist": x_sqdist}


# ---------------------------------------------------------------------------
# Sampling


@dataclass
class Posterior:
    """Posterior draws by chain (unconstrained sites) and how the sampler did.

    ``draws[name]`` has shape ``(chains, samples, ...)``.
    """

    draws: dict[str, np.ndarray]
    num_steps: np.ndarray          # (chains, samples) leapfrog steps per iteration
    warmup_num_steps: np.ndarray   # (chains, warmup)
    diverging: np.ndarray          # (chains, samples)
    step_size: np.ndarray          # (chains,)
    warmup_seconds: float
    sampling_seconds: float
    chain_method: str

    @property
    def seconds(self) -> float:
        return self.warmup_seconds + self.sampling_seconds


def initial_values(data: KohData, z_start: np.ndarray | None, chains: int,
                   random_state: int, spread: float = 0.3) -> dict[str, np.ndarray]:
    """Per-chain starting points: around ``z_start`` (else 0) and the prior medians.

    Each chain is jittered by ``spread`` standard deviations so that R-hat
    compares chains started apart.
    """
    rng = np.random.default_rng(random_state)
    k = len(data.active)
    centre = np.zeros(k) if z_start is None else np.clip(np.asarray(z_start)[data.active], -2.5, 2.5)
    n_ls = data.x_obs.shape[1] if data.ard else 1
    out = {"z": centre[None, :] + spread * rng.standard_normal((chains, k))}
    for name, size in (("log_discrepancy_std", None), ("log_discrepancy_lengthscale", n_ls),
                       ("log_noise_std", None)):
        mean, sd = data.priors[name]
        shape = (chains,) if size is None else (chains, size)
        out[name] = mean + spread * sd * rng.standard_normal(shape)
    return out


def sample_posterior(data: KohData, settings: BayesSettings, init: dict | None = None,
                     progress: bool = False) -> Posterior:
    """Run NUTS (NumPyro) with ``settings.chains`` chains; parallel when devices allow.

    Warm-up and sampling run (and are timed) separately; JIT compilation
    counts in the warm-up time.
    """
    import jax
    from numpyro.infer import MCMC, NUTS

    chains = settings.chains
    method = "parallel" if jax.local_device_count() >= chains and chains > 1 else "sequential"
    kernel = NUTS(make_model(data.ard, data.priors), target_accept_prob=settings.target_accept,
                  dense_mass=settings.dense_mass, max_tree_depth=settings.max_tree_depth)
    mcmc = MCMC(kernel, num_warmup=max(settings.warmup, 1), num_samples=settings.samples,
                num_chains=chains, chain_method=method, progress_bar=progress,
                jit_model_args=True)
    arrays = model_arrays(data)
    key = jax.random.PRNGKey(settings.seed)
    started = time.perf_counter()
    mcmc.warmup(key, arrays, init_params=init, extra_fields=("num_steps",),
                collect_warmup=True)
    warm = mcmc.get_extra_fields(group_by_chain=True)
    jax.block_until_ready(mcmc.post_warmup_state)
    warmed = time.perf_counter()
    mcmc.run(mcmc.post_warmup_state.rng_key, arrays,
             extra_fields=("num_steps", "diverging", "adapt_state.step_size"))
    draws = {k: np.asarray(v) for k, v in mcmc.get_samples(group_by_chain=True).items()}
    done = time.perf_counter()
    extra = mcmc.get_extra_fields(group_by_chain=True)
    return Posterior(draws=draws, num_steps=np.asarray(extra["num_steps"]),
                     warmup_num_steps=np.asarray(warm["num_steps"]),
                     diverging=np.asarray(extra["diverging"]),
                     step_size=np.asarray(extra["adapt_state.step_size"])[:, -1],
                     warmup_seconds=warmed - started, sampling_seconds=done - warmed,
                     chain_method=method)


# ---------------------------------------------------------------------------
# Diagnostics (Vehtari et al. 2021)


def _rank_normalise(draws: np.ndarray) -> np.ndarray:
    """Rank-normalise draws of shape (chains, samples) over all chains."""
    ranks = stats.rankdata(draws, axis=None).reshape(draws.shape)
    return special.ndtri((ranks - 0.375) / (draws.size + 0.25))


def rhat(draws: np.ndarray) -> float:
    """Rank-normalised split R-hat: max of the bulk and the folded (tail) versions."""
    from numpyro.diagnostics import split_gelman_rubin

    draws = np.asarray(draws, dtype=float)
    if draws.shape[1] < 4 or np.ptp(draws) == 0:
        return float("nan")
    bulk = split_gelman_rubin(_rank_normalise(draws))
    folded = split_gelman_rubin(_rank_normalise(np.abs(draws - np.median(draws))))
    return float(max(bulk, folded))


def ess_bulk(draws: np.ndarray) -> float:
    """Bulk effective sample size: ESS of the rank-normalised draws."""
    from numpyro.diagnostics import effective_sample_size

    draws = np.asarray(draws, dtype=float)
    if draws.shape[1] < 4 or np.ptp(draws) == 0:
        return float("nan")
    return float(effective_sample_size(_rank_normalise(draws)))


def ess_tail(draws: np.ndarray) -> float:
    """Tail effective sample size: the smaller ESS of the 5 % and 95 % quantile indicators."""
    from numpyro.diagnostics import effective_sample_size

    draws = np.asarray(draws, dtype=float)
    if draws.shape[1] < 4 or np.ptp(draws) == 0:
        return float("nan")
    out = []
    for q in (0.05, 0.95):
        indicator = (draws <= np.quantile(draws, q)).astype(float)
        out.append(float(effective_sample_size(indicator)) if np.ptp(indicator) > 0
                   else float("nan"))
    return float(np.nanmin(out)) if np.isfinite(out).any() else float("nan")


def scalar_draws(posterior: Posterior, names: dict[str, list[str]]) -> dict[str, np.ndarray]:
    """Each sampled scalar by name, shape (chains, samples); ``names`` labels vector sites."""
    out = {}
    for site, values in posterior.draws.items():
        labels = names.get(site)
        if values.ndim == 2:
            out[site] = values
        else:
            for j in range(values.shape[2]):
                label = labels[j] if labels and j < len(labels) else f"{site}[{j}]"
                out[label] = values[:, :, j]
    return out


@dataclass
class Convergence:
    """Convergence verdict with the figures behind it."""

    converged: bool
    reasons: list[str]
    rhat_max: float
    ess_bulk_min: float
    ess_tail_min: float
    divergences: int
    divergence_share: float
    per_quantity: dict[str, dict[str, float]]


def assess(posterior: Posterior, names: dict[str, list[str]], settings: BayesSettings
           ) -> Convergence:
    """R-hat, bulk/tail ESS per sampled scalar and the verdict against ``settings``."""
    per = {}
    for label, draws in scalar_draws(posterior, names).items():
        per[label] = {"rhat": rhat(draws), "ess_bulk": ess_bulk(draws), "ess_tail": ess_tail(draws)}

    def worst(key: str, pick) -> float:
        values = [v[key] for v in per.values()]
        if not values or not all(np.isfinite(values)):
            return float("nan")
        return float(pick(values))

    r = worst("rhat", max)
    bulk = worst("ess_bulk", min)
    tail = worst("ess_tail", min)
    divergences = int(posterior.diverging.sum())
    share = divergences / max(posterior.diverging.size, 1)
    reasons = []
    if not np.isfinite(r) or r > settings.rhat_max:
        reasons.append(f"R-hat {r:.3f} > {settings.rhat_max}" if np.isfinite(r)
                       else "R-hat undefined (too few draws per chain)")
    if not np.isfinite(bulk) or bulk < settings.ess_min:
        reasons.append(f"bulk ESS {bulk:.0f} < {settings.ess_min:g}")
    if not np.isfinite(tail) or tail < settings.ess_min:
        reasons.append(f"tail ESS {tail:.0f} < {settings.ess_min:g}")
    if share > settings.divergence_max:
        reasons.append(f"{divergences} divergent transitions ({share:.1%} > "
                       f"{settings.divergence_max:.1%})")
    return Convergence(converged=not reasons, reasons=reasons, rhat_max=r, ess_bulk_min=bulk,
                       ess_tail_min=tail, divergences=divergences, divergence_share=share,
                       per_quantity=per)


# ---------------------------------------------------------------------------
# Draws in physical terms and predictions


def flat_draws(posterior: Posterior) -> dict[str, np.ndarray]:
    """Draws with chains stacked: ``(chains * samples, ...)``."""
    return {k: v.reshape((-1,) + v.shape[2:]) for k, v in posterior.draws.items()}


def unit_draws(data: KohData, posterior: Posterior, random_state: int = 0) -> np.ndarray:
    """Prior-CDF values ``u`` of every calibration parameter per draw, ``(draws, k)``.

    Screened-out parameters are drawn from their prior (uniform ``u``).
    """
    flat = flat_draws(posterior)
    n = flat["z"].shape[0]
    rng = np.random.default_rng(random_state)
    unit = rng.uniform(size=(n, data.n_parameters))
    unit[:, data.active] = special.ndtr(flat["z"])
    return unit


def predictive(grid: GridEmulator, obs_rows: np.ndarray, target_rows: np.ndarray,
               y_obs: np.ndarray, unit: np.ndarray, log_sd_delta: np.ndarray,
               log_lengthscale: np.ndarray, log_sd_eps: np.ndarray, ard: bool,
               random_state: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """KOH posterior predictive of new observations at ``target_rows`` (standardised).

    For each draw: the Gaussian conditional of ``y(target)`` given the
    observations, the simulations, θ and φ_δ (emulator + discrepancy + noise),
    its mean and one draw from it.

    Returns
    -------
    means, samples : ndarray, shape (draws, n_target)
    """
    rng = np.random.default_rng(random_state)
    rows = np.concatenate([obs_rows, target_rows])
    n_obs = len(obs_rows)
    x = grid.x[rows]
    means, samples = [], []
    t_all = (unit - 0.5) * SQRT12
    mean_all = grid.predict_mean(t_all)[:, rows]
    for i in range(len(unit)):
        cov_eta = grid.predict_cov(t_all[i])[np.ix_(rows, rows)]
        ls = np.exp(np.atleast_1d(log_lengthscale[i]))
        scaled = x / (ls if ard else ls[0])
        sq = np.sum(scaled * scaled, axis=1)
        k_delta = np.exp(-0.5 * np.maximum(sq[:, None] + sq[None, :] - 2 * scaled @ scaled.T, 0))
        total = cov_eta + np.exp(2 * log_sd_delta[i]) * k_delta \
            + (np.exp(2 * log_sd_eps[i]) + _JITTER) * np.eye(len(rows))
        s_oo = total[:n_obs, :n_obs]
        s_to = total[n_obs:, :n_obs]
        chol = np.linalg.cholesky(s_oo)
        solve = np.linalg.solve(chol, s_to.T)
        resid = np.linalg.solve(chol, y_obs - mean_all[i, :n_obs])
        mean = mean_all[i, n_obs:] + solve.T @ resid
        cov = total[n_obs:, n_obs:] - solve.T @ solve
        jitter = 1e-10 * np.eye(len(target_rows))
        w, vecs = np.linalg.eigh(cov + jitter)
        draw = mean + vecs @ (np.sqrt(np.clip(w, 0, None)) * rng.standard_normal(len(w)))
        means.append(mean)
        samples.append(draw)
    return np.array(means), np.array(samples)
