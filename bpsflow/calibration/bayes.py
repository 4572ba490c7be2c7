"""Kennedy–O'Hagan calibration in NumPyro: the model, NUTS, convergence diagnostics.

The field observations (standardised) are ``y = η(x, θ) + δ(x) + ε``
(seed eq. 19). With the emulator's hyperparameters fixed (modular MLE), the
joint likelihood of simulations and observations (seed eq. 22) is the
likelihood of the simulations — a constant — times that of the observations
*conditioned on the simulations*:

    y | y_sim, θ, φ_δ ~ N( m(θ),  C_η(θ) + σ_δ² K_δ(x; ℓ_δ) + (σ_ε² + v_em) I ),

with ``m`` and ``C_η`` the emulator's conditional mean and covariance at
``(x_obs, θ)`` (:class:`bpsflow.calibration.emulator.BlockEmulator`: the
simulator block is factorised once; each step costs an ``n_obs × n_obs``
Cholesky) and ``v_em`` the emulator's squared error on held-out runs (the
GP's own variance ``C_η`` understates it by orders of magnitude). The
posterior is seed eq. 21. For many observations the ``lowrank`` likelihood
replaces ``K_δ`` by its FITC approximation on a few inducing inputs and keeps
the diagonal of ``C_η`` (``O(n m²)`` per step).

Parametrisation (the geometry NUTS sees):

* θ is non-centred through its prior's CDF: ``z ~ N(0, 1)``,
  ``u = Φ(z)``, ``θ = F⁻¹(u)``, so every calibration parameter has a
  standard normal prior whatever its distribution (the emulator takes
  ``u``).
* δ's standard deviation and length-scale(s) and σ_ε are sampled on the log
  scale with normal priors (lognormal priors: median and log-sd from the
  config; seed §4.3.5: ~20 % model bias, ~5 % observation error, in
  standardised output units).
* the posterior mode is found from the deterministic optimum (L-BFGS on JAX
  gradients); chains start from the Laplace approximation there, widened
  (so R-hat compares dispersed starts), and its covariance is the initial
  dense mass matrix that warm-up goes on adapting;
* calibration parameters whose effect on the emulator is negligible are not
  sampled — their posterior is their prior.

Diagnostics follow Vehtari et al. (2021): rank-normalised split R-hat (the
larger of bulk and folded), bulk ESS (rank-normalised) and tail ESS (the 5 %
and 95 % quantile indicators), computed with :mod:`numpyro.diagnostics`.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import special, stats

from bpsflow.calibration.emulator import NORMAL_SCORES, BlockEmulator
from bpsflow.calibration.settings import BayesSettings

_JITTER = 1e-8


def configure_jax(devices: int) -> None:
    """Ask XLA for ``devices`` CPU devices (one per chain) and float64.

    Call before JAX runs: parallel chains need one device each.

    The device count only takes effect if no JAX computation has run in the
    process yet; otherwise chains run one after another (still correct).
    """
    import numpyro

    devices = max(1, int(devices))
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        numpyro.set_host_device_count(devices)
    numpyro.enable_x64()
    enable_compilation_cache()


#: Environment variable naming the folder of XLA's compiled programs, or ``off``.
COMPILATION_CACHE_ENV = "BPSFLOW_JAX_CACHE"
#: Above this size the cache drops its least recently used programs (bytes).
_COMPILATION_CACHE_BYTES = 1 << 30


def compilation_cache_dir() -> Path | None:
    """Where compiled NUTS and likelihood programs are kept between runs (None: off).

    ``$BPSFLOW_JAX_CACHE`` (a folder, or ``off``), else JAX's own
    ``$JAX_COMPILATION_CACHE_DIR``, else ``jax`` in
    :func:`bpsflow.files.user_cache_dir` (``~/.cache/bpsflow/jax``).
    """
    from bpsflow.files import user_cache_dir

    chosen = os.environ.get(COMPILATION_CACHE_ENV) or os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if chosen is not None and chosen.strip().lower() in ("off", "0", "false", "none"):
        return None
    if chosen:
        return Path(chosen).expanduser()
    return user_cache_dir() / "jax"


def enable_compilation_cache() -> Path | None:
    """Keep XLA's compiled programs on disk (JAX's persistent compilation cache).

    Every NUTS run compiles its warm-up and sampling loops and the
    likelihood's gradient (tens of XLA programs, seconds each); a program of
    the same model, shapes and settings is then read back instead, in this
    process (the next scenario, truth or fold) and in later ones. A size
    limit makes JAX lock the folder, so parallel processes share it safely.
    The cache only saves time: a folder that cannot be written leaves it
    off, with the same results.
    """
    import jax

    folder = compilation_cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    if not os.access(folder, os.W_OK | os.X_OK):
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", _COMPILATION_CACHE_BYTES)
    return folder


@dataclass
class EmulatorBlock:
    """One emulator block's arrays at the observations it holds (standardised units)."""

    ux_obs: np.ndarray             # (n_g, B) rows of U_x at the block's observations
    mean_weights: np.ndarray       # (A, B)
    t_vectors: np.ndarray          # (R, A)
    inverse_d: np.ndarray          # (A, B)
    x_values: np.ndarray           # (B,)
    signal_variance: float
    t_scaled: np.ndarray           # (R, k_active) runs' t / ℓ_t
    inverse_lengthscales: np.ndarray  # (k_active,)
    log_base: np.ndarray           # (R,) log k_t over the screened-out parameters


@dataclass
class KohData:
    """Everything the likelihood needs, as arrays (standardised units).

    ``active`` lists the sampled calibration parameters (indices into θ);
    the others sit at their prior median in the emulator. The emulator's
    moments come block by block (:class:`~bpsflow.calibration.emulator.BlockEmulator`):
    ``blocks[g]`` holds the observations ``np.flatnonzero(obs_block == g)``, and
    ``unblock`` puts the blocks' concatenated values back in observation order.
    """

    y: np.ndarray                  # (n,) standardised observations
    blocks: tuple[EmulatorBlock, ...]
    unblock: np.ndarray            # (n,) observation i's position in the blocks' concatenation
    input_table: np.ndarray        # (k_active, G) emulator input t at each of NORMAL_SCORES
    x_obs: np.ndarray              # (n, d_x) standardised variable inputs
    active: np.ndarray             # (k_active,) indices of sampled parameters
    n_parameters: int
    ard: bool
    #: name -> (mean, sd) of the log of the quantity
    priors: dict[str, tuple[float, float]] = field(default_factory=dict)
    lowrank: bool = False
    x_inducing: np.ndarray | None = None   # (m, d_x) inducing inputs of δ (low-rank likelihood)
    extra_variance: np.ndarray | None = None  # (n,) known error variance (emulator error)
    #: (n, r) known correlated error: covariance F Fᵀ (the emulator's hold-out errors)
    extra_factor: np.ndarray | None = None
    noise_index: np.ndarray | None = None     # (n,) each observation's σ_ε (per-output noise)
    n_noise: int = 1                          # how many σ_ε: 1 shared, else one per output
    output_index: np.ndarray | None = None    # (n,) each observation's output (position)
    n_discrepancy: int = 1                    # how many σ_δ: 1 shared, else one per output


def koh_data(grid: BlockEmulator, obs_rows: np.ndarray, y: np.ndarray, active: np.ndarray,
             settings: BayesSettings, extra_variance: np.ndarray | None = None,
             obs_outputs: np.ndarray | None = None,
             extra_factor: np.ndarray | None = None) -> KohData:
    """Assemble the likelihood's arrays from the emulator and the observation rows.

    ``extra_variance`` (per observation, standardised) is a known error
    variance added to σ_ε² (the emulator's hold-out error); ``extra_factor``
    (per observation, ``r`` columns) a known error with covariance ``F Fᵀ``
    (the emulator's hold-out errors with their correlation between rows). ``obs_outputs``
    (per observation, the output's position) gives each output its own σ_ε
    when ``settings.noise_per_output`` is set, and its own δ scale σ_δ when
    ``settings.discrepancy_per_output`` is.
    """
    active = np.asarray(active, dtype=int)
    screened = np.setdiff1d(np.arange(grid.t.shape[1]), active)
    # parameters not sampled sit at their prior median
    centre = grid.inputs.centre
    obs_block, obs_position = grid.block_of(obs_rows)
    blocks = []
    for g, block in enumerate(grid.blocks):
        lengthscales = block.hyper.t_lengthscales
        log_base = -0.5 * np.sum(((block.t[:, screened] - centre[screened])
                                  / lengthscales[screened]) ** 2, axis=1)
        blocks.append(EmulatorBlock(
            ux_obs=block.x_vectors[obs_position[obs_block == g]],
            mean_weights=block.mean_weights, t_vectors=block.t_vectors,
            inverse_d=block.inverse_d, x_values=block.x_values,
            signal_variance=block.hyper.signal_variance,
            t_scaled=block.t[:, active] / lengthscales[active],
            inverse_lengthscales=1.0 / lengthscales[active], log_base=log_base))
    unblock = np.argsort(np.argsort(obs_block, kind="stable"), kind="stable")
    priors = {
        "log_discrepancy_std": (np.log(settings.discrepancy_std.median),
                                settings.discrepancy_std.log_sd),
        "log_discrepancy_lengthscale": (np.log(settings.discrepancy_lengthscale.median),
                                        settings.discrepancy_lengthscale.log_sd),
        "log_noise_std": (np.log(settings.noise_std.median), settings.noise_std.log_sd),
    }
    lowrank = settings.likelihood == "lowrank" or (
        settings.likelihood == "auto" and len(obs_rows) > settings.exact_max_observations)
    x_obs = grid.x[obs_rows]
    inducing = inducing_inputs(x_obs, settings.inducing_points, settings.seed) if lowrank else None
    return KohData(y=np.asarray(y, float), blocks=tuple(blocks), unblock=unblock,
                   input_table=grid.inputs.table[active],
                   x_obs=x_obs, active=active, n_parameters=grid.t.shape[1],
                   ard=settings.ard, priors=priors, lowrank=lowrank, x_inducing=inducing,
                   extra_variance=None if extra_variance is None
                   else np.asarray(extra_variance, dtype=float),
                   extra_factor=None if extra_factor is None
                   else np.asarray(extra_factor, dtype=float),
                   **_output_groups(settings, obs_outputs, len(obs_rows)))


def _output_groups(settings: BayesSettings, obs_outputs: np.ndarray | None, n: int) -> dict:
    """Which σ_ε and σ_δ each observation takes: one shared, or its output's own."""
    codes = np.zeros(n, dtype=int) if obs_outputs is None else np.asarray(obs_outputs, dtype=int)
    count = int(codes.max()) + 1 if n else 1
    own_noise = settings.noise_per_output and count > 1
    own_delta = settings.discrepancy_per_output and count > 1
    return {"noise_index": codes if own_noise else np.zeros(n, dtype=int),
            "n_noise": count if own_noise else 1, "output_index": codes,
            "n_discrepancy": count if own_delta else 1}


def inducing_inputs(x: np.ndarray, count: int, random_state: int) -> np.ndarray:
    """``count`` inducing inputs of δ: k-means centres of the observations' inputs."""
    from sklearn.cluster import KMeans

    if count >= len(x):
        return np.array(x, dtype=float)
    return KMeans(count, n_init=1, random_state=random_state).fit(x).cluster_centers_


def _emulator_moments(z, d: dict, full: bool = True):
    """Emulator mean and covariance (``full``) or variances at the observations (JAX).

    ``z`` is the non-centred θ of the sampled parameters. Each block gives
    its observations' moments; blocks are uncorrelated, so the covariance is
    block-diagonal.
    """
    import jax.numpy as jnp
    from jax.scipy.linalg import block_diag

    t = emulator_inputs(z, d["input_table"])
    means, moments = [], []
    for b in d["blocks"]:
        scaled = t * b["inverse_lengthscales"]
        log_w = b["log_base"] - 0.5 * jnp.sum((scaled[None, :] - b["t_scaled"]) ** 2, axis=1)
        v = b["t_basis"] @ jnp.exp(log_w)
        if not full:
            # the x-side projections are folded into (n, A) matrices once (model_arrays):
            # two matrix-vector products per step instead of four, on the sampler's hot path
            means.append(b["obs_mean_weights"] @ v)
            moments.append(jnp.clip(b["obs_prior_variance"] - b["obs_inverse_d"] @ (v * v),
                                    0.0, None))
            continue
        means.append(b["ux_obs"] @ (b["mean_weights_t"] @ v))
        s2, mu = b["signal_variance"], b["x_values"]
        c = jnp.clip(s2 * mu - s2 * s2 * mu * mu * (b["inverse_d_t"] @ (v * v)), 0.0, None)
        moments.append((b["ux_obs"] * c) @ b["ux_obs"].T)
    if len(means) == 1:
        return means[0], moments[0]
    unblock = d["unblock"]
    mean = jnp.concatenate(means)[unblock]
    if not full:
        return mean, jnp.concatenate(moments)[unblock]
    return mean, block_diag(*moments)[unblock][:, unblock]


def emulator_inputs(z, table):
    """Emulator inputs of normal scores ``z`` (k,): each row of ``table`` interpolated (JAX).

    The same linear interpolation on :data:`NORMAL_SCORES` as
    :meth:`ParameterInputs.from_normal`; scores beyond its ends keep the end values.
    """
    import jax.numpy as jnp

    first, step = float(NORMAL_SCORES[0]), float(NORMAL_SCORES[1] - NORMAL_SCORES[0])
    position = (jnp.clip(z, first, float(NORMAL_SCORES[-1])) - first) / step
    index = jnp.clip(jnp.floor(position).astype(jnp.int32), 0, len(NORMAL_SCORES) - 2)
    table = jnp.asarray(table)
    rows = jnp.arange(table.shape[0])
    low, high = table[rows, index], table[rows, index + 1]
    return low + (position - index) * (high - low)


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


def woodbury_terms(w, scaled):
    """``log det(I + W Wᵀ) − uᵀ (I + W Wᵀ)⁻¹ u``, ``u = W scaled``, with a hand-written gradient.

    The two terms the low-rank likelihood adds to the diagonal one (Woodbury's
    identity and the matrix determinant lemma). With ``A = I + W Wᵀ`` and
    ``β = A⁻¹ u``: ``∂/∂W = 2 A⁻¹ W − 2 β scaledᵀ + 2 β βᵀ W`` and
    ``∂/∂scaled = −2 Wᵀ β``. Differentiating through the Cholesky factor of
    ``A`` instead cost most of a NUTS step on the hourly hydronic scenarios
    (``A`` of 80-90 rows: 32 inducing inputs and the known error's columns).
    """
    return _woodbury_terms()(w, scaled)


def _woodbury_terms():
    import jax
    import jax.numpy as jnp
    from jax.scipy.linalg import cho_solve

    global _WOODBURY
    if _WOODBURY is not None:
        return _WOODBURY

    def forward(w, scaled):
        chol = jnp.linalg.cholesky(jnp.eye(w.shape[0]) + w @ w.T)
        u = w @ scaled
        beta = cho_solve((chol, True), u)
        return 2.0 * jnp.sum(jnp.log(jnp.diag(chol))) - u @ beta, (w, scaled, chol, beta)

    @jax.custom_vjp
    def terms(w, scaled):
        return forward(w, scaled)[0]

    def backward(saved, g):
        w, scaled, chol, beta = saved
        inverse_w = cho_solve((chol, True), w)                       # A⁻¹ W
        grad_w = 2.0 * (inverse_w - jnp.outer(beta, scaled) + jnp.outer(beta, beta @ w))
        return g * grad_w, -2.0 * g * (w.T @ beta)

    terms.defvjp(forward, backward)
    _WOODBURY = terms
    return terms


_WOODBURY = None


def _cross_kernel(a, b, log_lengthscale, ard: bool):
    """Unit-variance squared exponential between rows of ``a`` and ``b`` (JAX)."""
    import jax.numpy as jnp

    scale = jnp.exp(-log_lengthscale) if ard else jnp.exp(-log_lengthscale[0])
    a, b = a * scale, b * scale
    d2 = jnp.sum(a * a, 1)[:, None] + jnp.sum(b * b, 1)[None, :] - 2.0 * a @ b.T
    return jnp.exp(-0.5 * jnp.maximum(d2, 0.0))


def lowrank_log_density(residual, diagonal, sd_delta, log_lengthscale, d: dict, ard: bool,
                        factor=None):
    """``log N(residual; 0, D + S (Q + diag(1 - q)) S)`` with δ's FITC covariance (JAX).

    δ's kernel is replaced by its Nyström approximation on ``m`` inducing
    inputs ``Q = K_nm K_mm⁻¹ K_mn`` with the exact variances restored on the
    diagonal (FITC, Snelson & Ghahramani 2006); ``diagonal`` carries the
    emulator's variances and the noise. Woodbury's identity makes a step
    ``O(n m²)`` instead of ``O(n³)``. ``sd_delta`` is δ's standard deviation,
    a scalar or one per observation (``S = diag(sd_delta)``: each output's own
    scale on a shared correlation). ``factor`` (n × r) adds a known
    low-rank covariance ``F Fᵀ``; the Woodbury system is then ``m + r``.
    """
    import jax.numpy as jnp
    from jax.scipy.linalg import solve_triangular

    k_mm = _cross_kernel(d["x_inducing"], d["x_inducing"], log_lengthscale, ard)
    m = k_mm.shape[0]
    chol_m = jnp.linalg.cholesky(k_mm + 1e-6 * jnp.eye(m))
    v = solve_triangular(chol_m, _cross_kernel(d["x_inducing"], d["x_obs"], log_lengthscale, ard),
                         lower=True)                                      # (m, n)
    q = jnp.sum(v * v, axis=0)
    diag = diagonal + sd_delta ** 2 * jnp.clip(1.0 - q, 0.0, None) + _JITTER
    w = sd_delta * v / jnp.sqrt(diag)[None, :]                            # (m, n)
    if factor is not None:
        w = jnp.concatenate([w, factor.T / jnp.sqrt(diag)[None, :]])    # (m + r, n)
    scaled = residual / jnp.sqrt(diag)
    # log det(D + ...) = Σ log D + log det A; quad = sᵀs − uᵀ A⁻¹ u (A = I + W Wᵀ)
    return -0.5 * (scaled @ scaled + jnp.sum(jnp.log(diag)) + woodbury_terms(w, scaled)
                   + residual.shape[0] * jnp.log(2 * jnp.pi))


def make_model(ard: bool, priors: dict[str, tuple[float, float]], lowrank: bool = False,
               n_noise: int = 1, n_discrepancy: int = 1):
    """The NumPyro model of seed eq. 19–22 (see the module docstring).

    ``ard``, the priors, the number of σ_ε (``n_noise``: 1 shared, or one per
    output) and of σ_δ (``n_discrepancy``: 1 shared, or one per output, each
    scaling the output's rows and columns of δ's correlation) are fixed in
    the closure; the arrays (the data and the
    factorised simulator block) are the model's argument, so JAX compiles
    once for any data of the same shape.
    """
    def koh_model(d: dict) -> None:
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        k = d["input_table"].shape[0]
        z = numpyro.sample("z", dist.Normal(0.0, 1.0).expand([k]).to_event(1))
        m, s = priors["log_discrepancy_std"]
        if n_discrepancy == 1:
            log_sd_delta = numpyro.sample("log_discrepancy_std", dist.Normal(m, s))
            sd_delta = jnp.exp(log_sd_delta)[None]     # (1,): broadcasts over the rows
        else:
            log_sd_delta = numpyro.sample("log_discrepancy_std",
                                          dist.Normal(m, s).expand([n_discrepancy]).to_event(1))
            sd_delta = jnp.exp(log_sd_delta)[d["output_index"]]
        m, s = priors["log_discrepancy_lengthscale"]
        n_ls = d["x_obs"].shape[1] if ard else 1
        log_ls = numpyro.sample("log_discrepancy_lengthscale",
                                dist.Normal(m, s).expand([n_ls]).to_event(1))
        m, s = priors["log_noise_std"]
        if n_noise == 1:
            log_sd_eps = numpyro.sample("log_noise_std", dist.Normal(m, s))
            noise_variance = jnp.exp(2 * log_sd_eps) * jnp.ones_like(d["y"])
        else:
            log_sd_eps = numpyro.sample("log_noise_std",
                                        dist.Normal(m, s).expand([n_noise]).to_event(1))
            noise_variance = jnp.exp(2 * log_sd_eps)[d["noise_index"]]
        if lowrank:
            mean, variance = _emulator_moments(z, d, full=False)
            numpyro.factor("y", lowrank_log_density(
                d["y"] - mean, variance + noise_variance + d["extra_variance"],
                sd_delta, log_ls, d, ard, d["extra_factor"]))
            return
        mean, cov = _emulator_moments(z, d)
        total = (cov + sd_delta[:, None] * sd_delta[None, :] * _discrepancy_kernel(log_ls, d, ard)
                 + jnp.diag(d["extra_variance"])
                 + d["extra_factor"] @ d["extra_factor"].T
                 + jnp.diag(noise_variance + _JITTER))
        numpyro.factor("y", gaussian_log_density(total, d["y"] - mean))

    return koh_model


def model_arrays(data: KohData) -> dict:
    """The JAX-side arrays of :class:`KohData` (pairwise distances precomputed)."""
    x = data.x_obs
    sq = np.sum(x * x, axis=1)
    x_sqdist = np.maximum(sq[:, None] + sq[None, :] - 2.0 * x @ x.T, 0.0)
    return {"y": data.y, "blocks": [_block_arrays(block) for block in data.blocks],
            "unblock": data.unblock, "input_table": data.input_table,
            "x_obs": x, "x_sqdist": x_sqdist,
            "x_inducing": data.x_inducing if data.lowrank else np.zeros((1, x.shape[1])),
            "extra_variance": np.zeros(len(data.y)) if data.extra_variance is None
            else data.extra_variance,
            # no columns when there is none: no extra rows in the Woodbury system, no work
            "extra_factor": np.zeros((len(data.y), 0)) if data.extra_factor is None
            else data.extra_factor,
            "noise_index": np.zeros(len(data.y), dtype=int) if data.noise_index is None
            else data.noise_index,
            "output_index": np.zeros(len(data.y), dtype=int) if data.output_index is None
            else data.output_index}


def _block_arrays(block: EmulatorBlock) -> dict:
    """One emulator block's JAX-side arrays."""
    ux_squared = block.ux_obs * block.ux_obs
    s2 = block.signal_variance
    # transposed copies, contiguous: XLA's CPU matrix-vector products are slow on strided views
    return {"ux_obs": block.ux_obs,
            "mean_weights_t": np.ascontiguousarray(block.mean_weights.T),
            "t_basis": np.ascontiguousarray(block.t_vectors.T),
            "inverse_d_t": np.ascontiguousarray(block.inverse_d.T),
            "x_values": block.x_values, "signal_variance": np.float64(s2),
            "t_scaled": block.t_scaled, "inverse_lengthscales": block.inverse_lengthscales,
            "log_base": block.log_base,
            # the emulator's mean and variances at the observations as products with the
            # θ-side vector only (the low-rank likelihood's variances: the diagonal of C_η)
            "obs_mean_weights": np.ascontiguousarray(block.ux_obs @ block.mean_weights.T),
            "obs_prior_variance": ux_squared @ (s2 * block.x_values),
            "obs_inverse_d": np.ascontiguousarray(
                (ux_squared * (s2 * block.x_values) ** 2) @ block.inverse_d.T)}


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
    extensions: int = 0            # times every chain drew ``samples`` more (see extend_posterior)
    # per chain group: its NumPyro MCMC object, last state and model arrays, to draw on
    resume: list = field(default_factory=list, repr=False, compare=False)

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
    centre = (np.zeros(k) if z_start is None
              else np.clip(np.asarray(z_start)[data.active], -2.5, 2.5))
    n_ls = data.x_obs.shape[1] if data.ard else 1
    out = {"z": centre[None, :] + spread * rng.standard_normal((chains, k))}
    for name, size in (("log_discrepancy_std",
                        None if data.n_discrepancy == 1 else data.n_discrepancy),
                       ("log_discrepancy_lengthscale", n_ls),
                       ("log_noise_std", None if data.n_noise == 1 else data.n_noise)):
        mean, sd = data.priors[name]
        shape = (chains,) if size is None else (chains, size)
        out[name] = mean + spread * sd * rng.standard_normal(shape)
    return out


@dataclass
class Laplace:
    """The posterior mode (MAP) on the sampler's scale and the inverse Hessian there.

    ``covariance`` is ordered like NumPyro's flattened sites (sorted names).
    """

    mode: dict[str, np.ndarray]
    covariance: np.ndarray
    log_density: float
    seconds: float


def laplace(data: KohData, start: dict[str, np.ndarray]) -> Laplace:
    """Find the MAP from ``start`` (L-BFGS on JAX gradients) and the Laplace covariance.

    Used to start NUTS near the mode with a mass matrix that already fits the
    posterior's scales and correlations, which shortens warm-up.
    """
    import jax
    import jax.numpy as jnp
    from jax.flatten_util import ravel_pytree
    from numpyro.infer.util import potential_energy
    from scipy.optimize import minimize

    started = time.perf_counter()
    arrays = model_arrays(data)
    model = make_model(data.ard, data.priors, data.lowrank, data.n_noise, data.n_discrepancy)
    flat0, unravel = ravel_pytree({k: jnp.asarray(v) for k, v in start.items()})

    def energy(flat):
        return potential_energy(model, (arrays,), {}, unravel(flat))

    value_and_grad = jax.jit(jax.value_and_grad(energy))
    hessian = jax.jit(jax.hessian(energy))

    def fun(x):
        value, grad = value_and_grad(jnp.asarray(x))
        return float(value), np.asarray(grad, dtype=float)

    result = minimize(fun, np.asarray(flat0, dtype=float), jac=True, method="L-BFGS-B",
                      options={"maxiter": 500})
    h = np.asarray(hessian(jnp.asarray(result.x)), dtype=float)
    h = 0.5 * (h + h.T)
    w, v = np.linalg.eigh(h)
    # a flat or non-convex direction gets unit variance (the prior scale)
    w = np.where(w > 1e-6, w, 1.0)
    covariance = (v / w) @ v.T
    mode = {k: np.asarray(val) for k, val in unravel(jnp.asarray(result.x)).items()}
    return Laplace(mode=mode, covariance=covariance, log_density=-float(result.fun),
                   seconds=time.perf_counter() - started)


def laplace_starts(approx: Laplace, chains: int, random_state: int,
                   spread: float = 1.5) -> dict[str, np.ndarray]:
    """Chain starts drawn from the Laplace approximation widened ``spread`` times.

    Over-dispersed starts let R-hat detect chains that have not mixed.
    """
    from jax.flatten_util import ravel_pytree

    rng = np.random.default_rng(random_state)
    flat, unravel = ravel_pytree(approx.mode)
    chol = np.linalg.cholesky(approx.covariance + 1e-12 * np.eye(len(flat)))
    starts = [unravel(np.asarray(flat) + spread * chol @ rng.standard_normal(len(flat)))
              for _ in range(chains)]
    return {k: np.stack([np.asarray(s[k]) for s in starts]) for k in approx.mode}


def sample_posterior(data: KohData, settings: BayesSettings, init: dict | None = None,
                     progress: bool = False, inverse_mass_matrix: np.ndarray | None = None,
                     timed_warmup: bool = True) -> Posterior:
    """Run NUTS (NumPyro) with ``settings.chains`` chains, in parallel groups of one per device.

    ``init`` holds per-chain starts (arrays with a leading chain axis);
    ``inverse_mass_matrix`` an initial dense mass matrix (e.g.
    :attr:`Laplace.covariance`) that warm-up goes on adapting.

    Chains run ``settings.parallel_chains`` at a time (one XLA device each).
    By default all at once only for tiny problems (up to 30 observations),
    where a step is too short to use more than one core; otherwise one after
    another in one call (compiled once), each step's linear algebra spread
    over the cores by XLA. On 2 cores one device per chain, or per core, slows
    every leapfrog step more than it gains (``bench/results.json``,
    ``hydronic_nuts_chain_groups``).

    Warm-up and sampling run (and are timed) separately; JIT compilation
    counts in the warm-up time. ``timed_warmup=False`` runs both in one call
    (NumPyro compiles its sampling loop once per call, ~2 s: repeated small
    problems save that); warm-up is then neither timed nor its steps recorded.
    """
    import jax

    chains = settings.chains
    devices = max(1, jax.local_device_count())
    if chains == 1:
        method, group = "sequential", 1
    elif settings.chain_method not in ("auto", "parallel"):
        method, group = settings.chain_method, chains
    else:
        wanted = settings.parallel_chains or (chains if len(data.y) <= _SMALL_PROBLEM else 1)
        method, group = "parallel", max(1, min(chains, devices, wanted))
        if group == 1:
            method, group = "sequential", chains
    mass = None if inverse_mass_matrix is None or not settings.dense_mass \
        else np.asarray(inverse_mass_matrix)
    priors = tuple(sorted((k, tuple(map(float, v))) for k, v in data.priors.items()))
    arrays = model_arrays(data)
    parts = []
    warmup_seconds = sampling_seconds = 0.0
    for first in range(0, chains, group):
        size = min(group, chains - first)
        part_settings = settings.model_copy(update={"chains": size})
        mcmc = _mcmc(data.ard, priors, data.lowrank, part_settings,
                     method if size > 1 else "sequential", progress, mass, data.n_noise,
                     data.n_discrepancy)
        part_init = None if init is None else {k: np.asarray(v)[first:first + size]
                                               for k, v in init.items()}
        if part_init is not None and size == 1:   # NumPyro takes one chain's start unbatched
            part_init = {k: v[0] for k, v in part_init.items()}
        key = jax.random.fold_in(jax.random.PRNGKey(settings.seed), first)
        result = _run(mcmc, key, arrays, part_init, timed_warmup)
        result["resume"] = (mcmc, mcmc.last_state, arrays)
        parts.append(result)
        warmup_seconds += result["warmup_seconds"]
        sampling_seconds += result["sampling_seconds"]
    draws = {k: np.concatenate([p["draws"][k] for p in parts]) for k in parts[0]["draws"]}

    def joined(name: str) -> np.ndarray:
        return np.concatenate([p[name] for p in parts])

    groups = -(-chains // group)
    label = method if groups == 1 else f"{method} ({groups} groups of {group})"
    return Posterior(draws=draws, num_steps=joined("num_steps"),
                     warmup_num_steps=joined("warmup_num_steps"),
                     diverging=joined("diverging"), step_size=joined("step_size"),
                     warmup_seconds=warmup_seconds, sampling_seconds=sampling_seconds,
                     chain_method=label, resume=[p["resume"] for p in parts])


def extend_posterior(posterior: Posterior) -> Posterior:
    """Every chain draws as many samples again, carrying on from its last state.

    Warm-up is not repeated: the adapted step size and mass matrix and each
    chain's position carry over, so the longer chains are the chains NUTS
    would have drawn with more samples from the start. R-hat and ESS of the
    joined draws then judge longer chains (Vehtari et al. 2021 recommend
    running longer when R-hat exceeds 1.01).
    """
    if not posterior.resume:
        raise ValueError("this posterior keeps no sampler state to carry on from")
    parts, resume = [], []
    started = time.perf_counter()
    for mcmc, last_state, arrays in posterior.resume:
        mcmc.post_warmup_state = last_state
        mcmc.run(last_state.rng_key, arrays, extra_fields=_SAMPLE_FIELDS)
        parts.append(_sampled(mcmc))
        resume.append((mcmc, mcmc.last_state, arrays))
    seconds = time.perf_counter() - started

    def joined(name: str) -> np.ndarray:   # chain groups stacked, as sample_posterior does
        return np.concatenate([p[name] for p in parts])

    return Posterior(
        draws={k: np.concatenate([posterior.draws[k],
                                  np.concatenate([p["draws"][k] for p in parts])], axis=1)
               for k in posterior.draws},
        num_steps=np.concatenate([posterior.num_steps, joined("num_steps")], axis=1),
        warmup_num_steps=posterior.warmup_num_steps,
        diverging=np.concatenate([posterior.diverging, joined("diverging")], axis=1),
        step_size=joined("step_size"), warmup_seconds=posterior.warmup_seconds,
        sampling_seconds=posterior.sampling_seconds + seconds,
        chain_method=posterior.chain_method, extensions=posterior.extensions + 1, resume=resume)


_SMALL_PROBLEM = 30


#: Sampler statistics collected with every draw.
_SAMPLE_FIELDS = ("num_steps", "diverging", "adapt_state.step_size")


def _sampled(mcmc) -> dict:
    """The draws and statistics of an MCMC object's last sampling call, grouped by chain."""
    chains = mcmc.num_chains
    extra = mcmc.get_extra_fields(group_by_chain=True)
    return {"draws": {k: np.asarray(v) for k, v in mcmc.get_samples(group_by_chain=True).items()},
            "num_steps": np.asarray(extra["num_steps"]).reshape(chains, -1),
            "diverging": np.asarray(extra["diverging"]).reshape(chains, -1),
            "step_size": np.asarray(extra["adapt_state.step_size"]).reshape(chains, -1)[:, -1]}


def _run(mcmc, key, arrays: dict, init: dict | None, timed_warmup: bool) -> dict:
    """One NumPyro MCMC call: draws and sampler statistics grouped by chain."""
    import jax

    chains = mcmc.num_chains
    started = time.perf_counter()
    if not timed_warmup:
        # a reused MCMC object keeps its last warm-up state, and run() would skip warm-up
        mcmc.post_warmup_state = None
        mcmc.run(key, arrays, init_params=init, extra_fields=_SAMPLE_FIELDS)
        warm_steps = np.zeros((chains, 0))
        warmed = None
    else:
        mcmc.warmup(key, arrays, init_params=init, extra_fields=("num_steps",),
                    collect_warmup=True)
        warm_steps = np.asarray(mcmc.get_extra_fields(group_by_chain=True)["num_steps"])
        jax.block_until_ready(mcmc.post_warmup_state)
        warmed = time.perf_counter()
        mcmc.run(mcmc.post_warmup_state.rng_key, arrays, extra_fields=_SAMPLE_FIELDS)
    result = _sampled(mcmc)
    done = time.perf_counter()
    warmed = done if warmed is None else warmed
    return {**result, "warmup_num_steps": warm_steps.reshape(chains, -1),
            "warmup_seconds": warmed - started, "sampling_seconds": done - warmed}


_MCMC_CACHE: dict = {}
_JIT_MODEL_ARGS = True


def _mcmc(ard: bool, priors: tuple, lowrank: bool, settings: BayesSettings, method: str,
          progress: bool, inverse_mass_matrix: np.ndarray | None, n_noise: int = 1,
          n_discrepancy: int = 1):
    """A NumPyro MCMC object; reused for the same model and settings without a mass matrix.

    The model's arrays are arguments (``jit_model_args``), so a reused object
    samples new data of the same shapes without compiling again (repeated
    synthetic truths, tests).
    """
    import sys

    from numpyro.infer import MCMC, NUTS

    # tqdm's bar off a terminal is a stream of carriage returns (a 120 kB log of one run);
    # the workflow prints what runs and how long it took around it
    progress = progress and sys.stderr.isatty()
    key = (ard, priors, lowrank, settings.chains, settings.warmup, settings.samples,
           settings.target_accept, settings.dense_mass, settings.max_tree_depth, method, progress,
           n_noise, n_discrepancy)
    if inverse_mass_matrix is None and key in _MCMC_CACHE:
        return _MCMC_CACHE[key]
    kernel = NUTS(make_model(ard, dict(priors), lowrank, n_noise, n_discrepancy),
                  target_accept_prob=settings.target_accept,
                  dense_mass=settings.dense_mass, max_tree_depth=settings.max_tree_depth,
                  inverse_mass_matrix=inverse_mass_matrix)
    mcmc = MCMC(kernel, num_warmup=max(settings.warmup, 1), num_samples=settings.samples,
                num_chains=settings.chains, chain_method=method, progress_bar=progress,
                jit_model_args=_JIT_MODEL_ARGS)
    if inverse_mass_matrix is None:
        _MCMC_CACHE.clear()
        _MCMC_CACHE[key] = mcmc
    return mcmc


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


@dataclass
class Predictive:
    """KOH posterior predictive at target rows, per draw (standardised units).

    ``mean``: E[y | data, θ, φ]; ``sample``: one draw of a new observation;
    ``discrepancy``: E[δ | data, θ, φ] (the model bias the data imply).
    """

    mean: np.ndarray           # (draws, n_target)
    sample: np.ndarray         # (draws, n_target)
    discrepancy: np.ndarray    # (draws, n_target)


def predictive(grid: BlockEmulator, obs_rows: np.ndarray, target_rows: np.ndarray,
               y_obs: np.ndarray, unit: np.ndarray, log_sd_delta: np.ndarray,
               log_lengthscale: np.ndarray, log_sd_eps: np.ndarray, ard: bool,
               x_inducing: np.ndarray | None = None, extra_variance: np.ndarray | None = None,
               random_state: int = 0, noise_index: np.ndarray | None = None,
               extra_factor: np.ndarray | None = None) -> Predictive:
    """KOH posterior predictive of new observations at ``target_rows`` (standardised).

    For each draw: the Gaussian conditional of ``y(target)`` (emulator +
    discrepancy + noise) given the observations, the simulations, θ and φ_δ —
    its mean, one draw from it, and the conditional mean of δ alone.
    ``target_rows`` may repeat ``obs_rows`` (δ at the calibration rows).
    With ``x_inducing`` (the low-rank likelihood) δ's covariance is the same
    FITC approximation and the emulator keeps only its variances.
    ``extra_variance`` (per grid row, standardised) is the known error
    variance of the likelihood (the emulator's hold-out error). With one σ_ε
    (σ_δ) per output, ``log_sd_eps`` (``log_sd_delta``) has a column per
    output and ``noise_index`` (per grid row: the row's output) says which is
    the row's. ``extra_factor`` (per grid row, ``r`` columns) is the known
    correlated error of the likelihood, covariance ``F Fᵀ``; it is correlated
    between the observed and the target rows, so it enters the conditional
    mean like δ.
    """
    rng = np.random.default_rng(random_state)
    rows = np.concatenate([obs_rows, target_rows])
    n_obs, n_target = len(obs_rows), len(target_rows)
    x = grid.x[rows]
    means, samples, deltas = [], [], []
    t_all = grid.t_of_unit(unit)
    mean_all = grid.predict_mean(t_all)[:, rows]
    known = 0.0 if extra_factor is None else extra_factor[rows] @ extra_factor[rows].T
    for i in range(len(unit)):
        cov_eta = grid.predict_cov(t_all[i])[np.ix_(rows, rows)]
        ls = np.exp(np.atleast_1d(log_lengthscale[i]))
        ls = ls if ard else ls[0]
        sd_delta = np.exp(_per_row(log_sd_delta[i], noise_index, rows))
        scale = np.outer(sd_delta, sd_delta)
        if x_inducing is not None:
            cov_eta = np.diag(np.diag(cov_eta))
            k_mm = _se(x_inducing, x_inducing, ls) + 1e-6 * np.eye(len(x_inducing))
            k_nm = _se(x, x_inducing, ls)
            nystrom = k_nm @ np.linalg.solve(k_mm, k_nm.T)
            k_delta = scale * (nystrom + np.diag(np.clip(1.0 - np.diag(nystrom), 0.0, None)))
        else:
            k_delta = scale * _se(x, x, ls)
        extra = np.zeros(len(rows)) if extra_variance is None else extra_variance[rows]
        own = _per_row(log_sd_eps[i], noise_index, rows)
        noise = np.diag(np.exp(2 * own) + _JITTER + extra)
        total = cov_eta + k_delta + noise + known
        chol = np.linalg.cholesky(total[:n_obs, :n_obs])
        resid = np.linalg.solve(chol.T, np.linalg.solve(chol, y_obs - mean_all[i, :n_obs]))
        cross = total[n_obs:, :n_obs] - (noise[n_obs:, :n_obs])
        mean = mean_all[i, n_obs:] + cross @ resid
        solve = np.linalg.solve(chol, cross.T)
        cov = total[n_obs:, n_obs:] - solve.T @ solve
        w, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
        draw = mean + vecs @ (np.sqrt(np.clip(w, 0, None)) * rng.standard_normal(n_target))
        means.append(mean)
        samples.append(draw)
        deltas.append(k_delta[n_obs:, :n_obs] @ resid)
    return Predictive(mean=np.array(means), sample=np.array(samples),
                      discrepancy=np.array(deltas))


def _per_row(values, output_index: np.ndarray | None, rows: np.ndarray) -> np.ndarray:
    """One draw's shared value, or its per-output values, at each of ``rows``."""
    values = np.atleast_1d(values)
    if output_index is not None and len(values) > 1:
        return values[output_index[rows]]
    return np.full(len(rows), values[0])


def _se(a: np.ndarray, b: np.ndarray, lengthscale) -> np.ndarray:
    a, b = a / lengthscale, b / lengthscale
    d2 = np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None, :] - 2.0 * a @ b.T
    return np.exp(-0.5 * np.maximum(d2, 0.0))
