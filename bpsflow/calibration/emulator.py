"""The GP emulator of the simulator η(x, t) (seed §4.3.4, eq. 20), hold-out tested.

A zero-mean Gaussian process with the ARD squared-exponential kernel of seed
eq. 20,

    c(d, d') = s² exp(-½ Σ_s (d_s - d'_s)² / ℓ_s²),   d = (x, t),

on standardised inputs (each variable input x by its mean and standard
deviation over the rows; each calibration parameter as ``(u - ½)·√12`` of its
prior CDF value ``u``, so the design is uniform with unit variance) and
standardised outputs (each output type by its mean and standard deviation
over the simulations, seed §4.3.1). ``s² = 1/λ_η`` and ``ℓ_s² = 1/β_ηs`` in
the seed's notation; a nugget σ_n² plays the computation error ε_en.

**Hyperparameters** are maximum-likelihood estimates (modular, Bayarri et al.
2007) from scikit-learn on ``points`` (run, row) pairs drawn from the
training runs — the subsample keeps the fit to seconds.

**Conditioning** uses every simulated value: each run covers every row
(time, output) of the calibration and held-out periods, so the simulation
data form a grid ``runs × rows`` and the kernel factorises, ``K = s² K_t ⊗
K_x + σ_n² I``. With the eigendecompositions ``K_t = U_t Λ U_tᵀ`` and
``K_x = U_x M U_xᵀ`` (factorised once) the emulator's mean and covariance at
``(x_rows, θ)`` cost ``O(R² + R·M)`` and ``O(M³)`` instead of ``O((R·M)³)``:

    mean(θ) = s² U_x (μ ⊙ Zᵀ v),         v = U_tᵀ k_t(θ, T),
    cov(θ)  = U_x diag(s² μ − s⁴ μ² ⊙ e) U_xᵀ,   e_b = Σ_a v_a² / D_ab,

where ``D_ab = s² λ_a μ_b + σ_n²`` and ``Z = (U_tᵀ Y U_x) / D``. This is the
exact GP conditional on all ``R·M`` simulated values (the joint likelihood of
seed eq. 22 factorised once into the simulator block and the field data given
it).

**Blocks**: with ``calibration.emulator.hyperparameters: per_output`` (the
default) each output is its own GP with its own hyperparameters and grid
(:class:`BlockEmulator`); with ``shared`` one GP covers every row, the output
type entering as a variable input.

**Test**: the emulator conditioned on the training runs predicts the
``test_fraction`` held-out runs at every row; R² and RMSE are reported
(seed Figure 4.6).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

SQRT12 = float(np.sqrt(12.0))

# Eigenvalues of K_x below this fraction of the largest are numerical zeros.
_EIG_RTOL = 1e-12


def standardise_unit(unit: np.ndarray) -> np.ndarray:
    """Prior-CDF values ``u`` in (0, 1) as emulator inputs ``(u - ½)·√12`` (unit variance)."""
    return (np.asarray(unit, dtype=float) - 0.5) * SQRT12


# Normal scores at which each parameter's emulator input is tabulated: ±6 holds all but
# 2e-9 of a prior; a step of 0.005 keeps linear interpolation within ~1e-6 of the map.
NORMAL_SCORES = np.linspace(-6.0, 6.0, 2401)


@dataclass(frozen=True)
class ParameterInputs:
    """How each calibration parameter enters the emulator: a monotone map of its normal score.

    The sampler moves θ as normal scores ``z`` (``u = Φ(z)`` is the prior CDF
    value); the emulator sees ``g_j(z)``, tabulated at :data:`NORMAL_SCORES`
    and interpolated linearly, the same way in NumPy and in the sampler's JAX
    code. ``kinds[j]`` says which map column ``j`` uses:

    * ``value``: the parameter's value, standardised by its prior mean and
      standard deviation. Simulated outputs are smooth in the physical value;
      through the CDF a lognormal leakage area's effect bends sharply in its
      upper tail, which a stationary kernel can follow only with short
      length-scales everywhere;
    * ``unit``: ``(u - ½)·√12`` (uniform with unit variance), for priors whose
      quantile function has steps (discrete, empirical) and on request.
    """

    table: np.ndarray                     # (k, G) emulator input at each normal score
    kinds: tuple[str, ...]

    @property
    def centre(self) -> np.ndarray:
        """Each parameter's emulator input at its prior median (``z = 0``), shape (k,)."""
        return self.table[:, len(NORMAL_SCORES) // 2]

    def from_normal(self, scores: np.ndarray) -> np.ndarray:
        """Emulator inputs of normal scores ``(n, k)``."""
        scores = np.atleast_2d(np.asarray(scores, dtype=float))
        return np.column_stack([np.interp(scores[:, j], NORMAL_SCORES, self.table[j])
                                for j in range(self.table.shape[0])])

    def from_unit(self, unit: np.ndarray) -> np.ndarray:
        """Emulator inputs of prior-CDF values ``(n, k)``."""
        return self.from_normal(_normal_scores(np.atleast_2d(unit)))

    def column(self, j: int, unit: np.ndarray) -> np.ndarray:
        """Emulator inputs of parameter ``j`` at prior-CDF values ``unit`` (1-D)."""
        return np.interp(_normal_scores(unit), NORMAL_SCORES, self.table[j])


def _normal_scores(unit) -> np.ndarray:
    """``Φ⁻¹(u)`` of prior-CDF values, kept finite at 0 and 1."""
    from scipy import special

    return special.ndtri(np.clip(np.asarray(unit, dtype=float), 1e-12, 1 - 1e-12))


def unit_inputs(count: int) -> ParameterInputs:
    """Every parameter as ``(u - ½)·√12`` of its prior CDF value."""
    from scipy import special

    row = standardise_unit(special.ndtr(NORMAL_SCORES))
    return ParameterInputs(table=np.tile(row, (count, 1)), kinds=("unit",) * count)


def value_inputs(to_values: Callable[[np.ndarray], np.ndarray], count: int) -> ParameterInputs:
    """Every parameter as its value standardised by its prior's mean and standard deviation.

    ``to_values`` maps prior-CDF values ``(n, count)`` to parameter values. A
    parameter whose values do not rise strictly over the central normal scores
    (a quantile function with steps) keeps the ``unit`` map.
    """
    from scipy import special, stats

    unit = np.tile(special.ndtr(NORMAL_SCORES)[:, None], (1, count))
    values = np.asarray(to_values(unit), dtype=float).T              # (count, G)
    weights = stats.norm.pdf(NORMAL_SCORES)
    weights = weights / weights.sum()
    central = np.abs(NORMAL_SCORES) <= 3.0
    fallback = unit_inputs(1).table[0]
    table, kinds = [], []
    for row in values:
        steps = np.diff(row)
        if np.all(np.isfinite(row)) and np.all(steps >= 0) and np.all(steps[central[1:]] > 0):
            mean = float(weights @ row)
            table.append((row - mean) / float(np.sqrt(weights @ (row - mean) ** 2)))
            kinds.append("value")
        else:
            table.append(fallback)
            kinds.append("unit")
    return ParameterInputs(table=np.array(table), kinds=tuple(kinds))


@dataclass(frozen=True)
class Scaling:
    """Standardisation of variable inputs (per column) and outputs (per output type)."""

    x_columns: tuple[str, ...]
    x_mean: np.ndarray
    x_std: np.ndarray
    outputs: tuple[str, ...]
    y_mean: np.ndarray          # per output, in its unit
    y_std: np.ndarray           # per output, in its unit
    dropped: tuple[str, ...] = ()

    def x(self, frame: pd.DataFrame) -> np.ndarray:
        return (frame[list(self.x_columns)].to_numpy(dtype=float) - self.x_mean) / self.x_std

    def output_index(self, outputs) -> np.ndarray:
        """Position in :attr:`outputs` of each of ``outputs``."""
        lookup = {o: i for i, o in enumerate(self.outputs)}
        return np.array([lookup[o] for o in outputs])

    def y(self, values: np.ndarray, outputs) -> np.ndarray:
        """Standardise ``values`` (rows first) of the given per-row ``outputs``."""
        i = self.output_index(outputs)
        shape = (-1,) + (1,) * (np.ndim(values) - 1)
        return (values - self.y_mean[i].reshape(shape)) / self.y_std[i].reshape(shape)

    def y_back(self, values: np.ndarray, outputs) -> np.ndarray:
        """Undo :meth:`y`: rows on the last axis."""
        i = self.output_index(outputs)
        return values * self.y_std[i] + self.y_mean[i]


def make_scaling(x: pd.DataFrame, outputs: pd.Series, simulated: np.ndarray) -> Scaling:
    """Scaling from the rows' variable inputs and the simulated values (rows × runs).

    Variable inputs that do not vary over the rows are dropped (recorded).
    """
    std = x.std(axis=0, ddof=0).to_numpy()
    keep = std > 1e-12 * np.maximum(1.0, np.abs(x.mean(axis=0).to_numpy()))
    names = tuple(np.asarray(x.columns)[keep])
    dropped = tuple(np.asarray(x.columns)[~keep])
    order = tuple(pd.unique(outputs))
    mean = np.array([simulated[(outputs == o).to_numpy()].mean() for o in order])
    spread = np.array([simulated[(outputs == o).to_numpy()].std() for o in order])
    spread = np.where(spread > 0, spread, 1.0)
    return Scaling(x_columns=names, x_mean=x.mean(axis=0).to_numpy()[keep], x_std=std[keep],
                   outputs=order, y_mean=mean, y_std=spread, dropped=dropped)


@dataclass(frozen=True)
class Hyperparameters:
    """Emulator hyperparameters (seed eq. 20): ``s² = 1/λ_η``, ``ℓ = β_η^-½``, nugget σ_n²."""

    signal_variance: float
    x_lengthscales: np.ndarray
    t_lengthscales: np.ndarray
    nugget: float
    log_marginal_likelihood: float = float("nan")
    fit_seconds: float = 0.0
    notes: tuple[str, ...] = ()
    #: τ²: each row's own response to θ, shared by the runs (``K_x + τ² I``; see
    #: :func:`fit_grid_hyperparameters`); 0 for a fit on scattered points
    row_variance: float = 0.0


# Deterministic starts of the hyperparameters' MLE: (variable-input, calibration-input)
# length-scales, standardised units. The first starts the calibration parameters long
# (they move the outputs less than the weather does, which saves optimiser iterations);
# from it alone L-BFGS can fall into a basin where every length-scale is short and the
# nugget explains most of the variance (seen on a daily, heating-only design, where the
# emulator then predicted nothing on its held-out runs), which the isotropic start avoids.
# The second start is fitted when the first fit's nugget carries more than
# _NUGGET_SHARE_MAX of the variance (a simulator is deterministic: its nugget is numerical
# error), and the larger marginal likelihood is kept.
_MLE_STARTS = ((1.5, 10.0), (3.0, 3.0))
_NUGGET_SHARE_MAX = 0.01


def fit_hyperparameters(x: np.ndarray, t: np.ndarray, y: np.ndarray, restarts: int = 1,
                        random_state: int = 0) -> Hyperparameters:
    """Maximum-likelihood hyperparameters of the ARD squared-exponential GP (scikit-learn).

    The marginal likelihood is maximised from the deterministic starts
    ``_MLE_STARTS`` in turn (plus ``restarts`` random ones from each,
    scikit-learn's ``n_restarts_optimizer``) until a fit's nugget is at most
    ``_NUGGET_SHARE_MAX`` of the variance, and the best optimum is kept;
    every start's optimum is listed in the notes.

    Parameters
    ----------
    x : ndarray, shape (n, d_x)
        Standardised variable inputs.
    t : ndarray, shape (n, k)
        Standardised calibration inputs.
    y : ndarray, shape (n,)
        Standardised outputs.
    """
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    started = time.perf_counter()
    inputs = np.hstack([x, t])
    fits, notes = [], set()
    for x_start, t_start in _MLE_STARTS:
        start = np.concatenate([np.full(x.shape[1], x_start), np.full(t.shape[1], t_start)])
        kernel = (ConstantKernel(1.0, (1e-3, 1e3))
                  * RBF(length_scale=start, length_scale_bounds=(5e-2, 1e3))
                  + WhiteKernel(1e-3, (1e-6, 1.0)))
        gp = GaussianProcessRegressor(kernel, normalize_y=False, n_restarts_optimizer=restarts,
                                      random_state=random_state, copy_X_train=False)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ConvergenceWarning)
            gp.fit(inputs, y)
        # a length-scale at its upper bound means "no effect": expected, and reported
        notes |= {str(w.message).split(".")[0] for w in caught
                  if issubclass(w.category, ConvergenceWarning)}
        fits.append((float(gp.log_marginal_likelihood_value_), gp.kernel_))
        nugget, signal = gp.kernel_.k2.noise_level, gp.kernel_.k1.k1.constant_value
        if nugget <= _NUGGET_SHARE_MAX * (nugget + signal):
            break
    best = int(np.argmax([lml for lml, _ in fits]))
    log_likelihood, learned = fits[best]
    notes.add("MLE from " + ", ".join(f"start {i + 1}: log marginal likelihood {lml:.1f}"
                                      for i, (lml, _) in enumerate(fits))
              + f"; kept start {best + 1}")
    lengthscales = np.atleast_1d(learned.k1.k2.length_scale).astype(float)
    d_x = x.shape[1]
    return Hyperparameters(signal_variance=float(learned.k1.k1.constant_value),
                           x_lengthscales=lengthscales[:d_x], t_lengthscales=lengthscales[d_x:],
                           nugget=float(learned.k2.noise_level),
                           log_marginal_likelihood=log_likelihood,
                           fit_seconds=time.perf_counter() - started, notes=tuple(sorted(notes)))


# Bounds of the grid fit: signal variance and length-scales as the scattered fit's. A
# simulator is deterministic, so its nugget may fall below the scattered fit's 1e-6, but
# not so far that s² / σ_n² (up to 1e10) costs the predictive variance its precision
_GRID_BOUNDS = {"signal_variance": (1e-3, 1e3), "row_variance": (1e-8, 10.0),
                "nugget": (1e-7, 1.0), "lengthscale": (5e-2, 1e3)}
#: τ² where the grid fit starts (a twentieth of the unit-variance K_x)
_ROW_VARIANCE_START = 0.05
# L-BFGS-B iterations of the grid fit: the hydronic floor's blocks converge in 20-40 (after
# 20, within 10 of 2e5 in log likelihood); the cap bounds a flat likelihood's cost
_GRID_ITERATIONS = 100


def _squared_distances(a: np.ndarray) -> np.ndarray:
    """``(a_i,s - a_j,s)²`` for every pair of rows and column, shape (s, n, n)."""
    return (a.T[:, :, None] - a.T[:, None, :]) ** 2


def grid_negative_log_likelihood(log_parameters: np.ndarray, x: np.ndarray, t: np.ndarray,
                                 y: np.ndarray, x_distances: np.ndarray | None = None,
                                 t_distances: np.ndarray | None = None
                                 ) -> tuple[float, np.ndarray]:
    """Negative log marginal likelihood of a whole ``runs × rows`` grid, and its gradient.

    The grid ``y`` (R, M) is modelled as ``vec(Y) ~ N(0, s² K_t ⊗ (K_x + τ² I)
    + σ_n² I)`` (row-major ``vec``): the emulator's kernel (seed eq. 20) with a
    row term τ², a response to θ that is each row's own and that every run
    shares. With ``K_t = U_t Λ U_tᵀ``, ``K_x = U_x M U_xᵀ``, ``D_ab = s² λ_a
    (μ_b + τ²) + σ_n²``, ``Ỹ = U_tᵀ Y U_x`` and ``A = Ỹ / D`` (Saatçi 2012,
    ch. 5)::

        −log L = ½ Σ Ỹ² / D + ½ Σ log D + ½ R M log 2π

    and for a kernel parameter ``p`` the gradient ``½ tr(K⁻¹ ∂K) − ½ αᵀ ∂K α``
    (Rasmussen & Williams 2006, eq. 5.9) in the same bases: for a length-scale
    of ``t``, ``½ s² Σ ∂K_t ⊙ (U_t diag(w) U_tᵀ − U_t A (M + τ²) Aᵀ U_tᵀ)`` with
    ``w_a = Σ_b (μ_b + τ²) / D_ab``; for one of ``x`` the same with the roles
    swapped; ``O(R³ + M³)`` per evaluation instead of ``O((R M)³)``.

    Parameters
    ----------
    log_parameters : ndarray, shape (3 + d_x + k,)
        ``log s², log τ², log σ_n²``, then the log length-scales of ``x`` and ``t``.
    x : ndarray, shape (M, d_x)
    t : ndarray, shape (R, k)
    y : ndarray, shape (R, M)
        Standardised outputs.
    x_distances, t_distances : ndarray, optional
        ``_squared_distances(x)`` and ``(t)``, when the caller evaluates many times.

    Returns
    -------
    value : float
    gradient : ndarray, shape (3 + d_x + k,)
        With respect to ``log_parameters``.
    """
    d_x = x.shape[1]
    s2, tau2, nugget = np.exp(log_parameters[:3])
    x_scales, t_scales = np.exp(log_parameters[3:3 + d_x]), np.exp(log_parameters[3 + d_x:])
    kt = squared_exponential(t, t, t_scales)
    kx = squared_exponential(x, x, x_scales)
    lam, ut = np.linalg.eigh(kt)
    mu, ux = np.linalg.eigh(kx)
    lam, mu = np.clip(lam, 0.0, None), np.clip(mu, 0.0, None)
    rows_values = mu + tau2
    d = s2 * lam[:, None] * rows_values[None, :] + nugget
    y_rotated = ut.T @ y @ ux
    a = y_rotated / d
    value = 0.5 * float(np.sum(y_rotated * a) + np.sum(np.log(d))
                        + y.size * np.log(2.0 * np.pi))
    residual = 1.0 / d - a * a                    # diagonal of K⁻¹ − ααᵀ in the eigenbases
    gradient = np.empty(len(log_parameters))
    gradient[0] = 0.5 * np.sum(s2 * lam[:, None] * rows_values[None, :] * residual)
    gradient[1] = 0.5 * np.sum(s2 * tau2 * lam[:, None] * residual)
    gradient[2] = 0.5 * nugget * np.sum(residual)
    # length-scales: ∂K_t/∂log ℓ_s = K_t ⊙ (Δ_s / ℓ_s)², not diagonal in U_t
    weight_t = (ut * ((rows_values[None, :] / d).sum(1))) @ ut.T \
        - (ut @ (a * rows_values[None, :]) @ a.T) @ ut.T
    weight_x = (ux * ((lam[:, None] / d).sum(0))) @ ux.T - (ux @ (a.T * lam[None, :]) @ a) @ ux.T
    x_distances = _squared_distances(x) if x_distances is None else x_distances
    t_distances = _squared_distances(t) if t_distances is None else t_distances
    gradient[3:3 + d_x] = 0.5 * s2 * np.einsum("sij,ij->s", x_distances, kx * weight_x) \
        / x_scales ** 2
    gradient[3 + d_x:] = 0.5 * s2 * np.einsum("sij,ij->s", t_distances, kt * weight_t) \
        / t_scales ** 2
    return value, gradient


def fit_grid_hyperparameters(x: np.ndarray, t: np.ndarray, y: np.ndarray,
                             start: Hyperparameters) -> Hyperparameters:
    """Hyperparameters and row term τ² that maximise the whole grid's marginal likelihood.

    A scattered-point fit (:func:`fit_hyperparameters`) sees each row in a
    run or two, so a row's own departure from what its variable inputs
    explain (the building's thermal history behind one hour's heating, which
    outdoor temperature and hour of day do not carry) looks like noise there,
    and is fitted as a nugget. Over the grid every run sees every row, and
    that departure is what it is: a function of θ shared by the runs, the
    row term τ² of :func:`grid_negative_log_likelihood`. L-BFGS-B from
    ``start``'s optimum (τ² from ``_ROW_VARIANCE_START``), with the exact
    gradient.

    Parameters
    ----------
    x : ndarray, shape (M, d_x)
    t : ndarray, shape (R, k)
    y : ndarray, shape (R, M)
        Standardised outputs of the training runs at every row.
    start : Hyperparameters
        The scattered-point fit.
    """
    from scipy.optimize import minimize

    started = time.perf_counter()
    d_x, k = x.shape[1], t.shape[1]
    bounds = np.log([_GRID_BOUNDS[name] for name in ("signal_variance", "row_variance",
                                                     "nugget")]
                    + [_GRID_BOUNDS["lengthscale"]] * (d_x + k))
    # the scattered fit's optimum, moved inside the grid fit's bounds
    initial = np.clip(np.log(np.concatenate([
        [start.signal_variance, _ROW_VARIANCE_START, start.nugget],
        start.x_lengthscales, start.t_lengthscales])), bounds[:, 0], bounds[:, 1])
    result = minimize(grid_negative_log_likelihood, initial, jac=True,
                      args=(x, t, y, _squared_distances(x), _squared_distances(t)),
                      method="L-BFGS-B", bounds=bounds, options={"maxiter": _GRID_ITERATIONS})
    fitted = np.exp(result.x)
    note = (f"grid fit over {t.shape[0]} runs x {x.shape[0]} rows: log marginal likelihood "
            f"{-result.fun:.1f} ({result.nit} L-BFGS-B iterations"
            + ("" if result.success else f"; stopped: {result.message}") + ")")
    return Hyperparameters(signal_variance=float(fitted[0]), row_variance=float(fitted[1]),
                           nugget=float(fitted[2]), x_lengthscales=fitted[3:3 + d_x],
                           t_lengthscales=fitted[3 + d_x:], log_marginal_likelihood=-result.fun,
                           fit_seconds=start.fit_seconds + time.perf_counter() - started,
                           notes=start.notes + (note,))


def squared_exponential(a: np.ndarray, b: np.ndarray, lengthscales: np.ndarray) -> np.ndarray:
    """``exp(-½ Σ (a - b)² / ℓ²)`` between the rows of ``a`` and ``b`` (unit variance)."""
    a = np.asarray(a, dtype=float) / lengthscales
    b = np.asarray(b, dtype=float) / lengthscales
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
    return np.exp(-0.5 * np.maximum(d2, 0.0))


@dataclass
class GridEmulator:
    """The emulator conditioned on a ``runs × rows`` grid of simulations (Kronecker form).

    Attributes
    ----------
    x : ndarray, shape (M, d_x)
        Standardised variable inputs of the rows.
    t : ndarray, shape (R, k)
        Emulator inputs of the runs' calibration parameters (see ``inputs``).
    hyper : Hyperparameters
    input_map : ParameterInputs, optional
        The map from prior-CDF values to ``t`` (default: :func:`unit_inputs`).
    """

    x: np.ndarray
    t: np.ndarray
    y: np.ndarray
    hyper: Hyperparameters
    input_map: ParameterInputs | None = None   # how θ maps to ``t`` (default: unit inputs)
    t_vectors: np.ndarray = field(init=False, repr=False)     # U_t (R, A)
    t_values: np.ndarray = field(init=False, repr=False)      # λ (A,)
    x_vectors: np.ndarray = field(init=False, repr=False)     # U_x (M, B)
    x_values: np.ndarray = field(init=False, repr=False)      # μ (B,)
    inverse_d: np.ndarray = field(init=False, repr=False)     # 1 / D (A, B)
    z: np.ndarray = field(init=False, repr=False)             # Z (A, B)

    def __post_init__(self) -> None:
        if self.input_map is None:
            self.input_map = unit_inputs(self.t.shape[1])
        h = self.hyper
        kt = squared_exponential(self.t, self.t, h.t_lengthscales)
        kx = squared_exponential(self.x, self.x, h.x_lengthscales)
        lam, ut = np.linalg.eigh(kt)
        mu, ux = np.linalg.eigh(kx)
        # Directions with eigenvalues at rounding level carry only the nugget: the
        # mean and covariance they add are ~1e-7 and ~1e-10 of the kept ones. The row
        # term lifts every direction of K_x by τ², so with it none is dropped.
        keep = mu > _EIG_RTOL * mu.max() if h.row_variance <= 0 else np.ones(len(mu), bool)
        mu, ux = np.clip(mu[keep], 0.0, None) + h.row_variance, ux[:, keep]
        keep = lam > _EIG_RTOL * lam.max()
        lam, ut = lam[keep], ut[:, keep]
        d = h.signal_variance * lam[:, None] * mu[None, :] + h.nugget
        self.t_vectors, self.t_values = ut, lam
        self.x_vectors, self.x_values = ux, mu
        self.inverse_d = 1.0 / d
        self.z = (ut.T @ self.y @ ux) * self.inverse_d

    @property
    def mean_weights(self) -> np.ndarray:
        """``s² Z ⊙ μ`` (A, B): the posterior mean is ``U_x (weightsᵀ v)``."""
        return self.hyper.signal_variance * self.z * self.x_values[None, :]

    @property
    def inputs(self) -> ParameterInputs:
        """The map from prior-CDF values to ``t``."""
        assert self.input_map is not None
        return self.input_map

    def t_of_unit(self, unit: np.ndarray) -> np.ndarray:
        """Emulator inputs ``t`` of prior-CDF values ``(n, k)``."""
        return self.inputs.from_unit(unit)

    def t_kernel(self, t_new: np.ndarray) -> np.ndarray:
        return squared_exponential(np.atleast_2d(t_new), self.t, self.hyper.t_lengthscales)

    def predict_mean(self, t_new: np.ndarray) -> np.ndarray:
        """Posterior mean at every row for each ``t_new`` (B, k) -> (B, M), standardised."""
        v = self.t_kernel(t_new) @ self.t_vectors
        return (v @ self.mean_weights) @ self.x_vectors.T

    def predict_cov(self, t_new: np.ndarray) -> np.ndarray:
        """Posterior covariance over the rows at one ``t_new`` (k,) -> (M, M), standardised."""
        v = self.t_kernel(t_new)[0] @ self.t_vectors
        s2, mu = self.hyper.signal_variance, self.x_values
        e = (v * v) @ self.inverse_d
        c = np.clip(s2 * mu - s2 * s2 * mu * mu * e, 0.0, None)
        return (self.x_vectors * c) @ self.x_vectors.T


@dataclass
class BlockEmulator:
    """Independent grid emulators of disjoint row blocks, on the same design runs.

    Each block is a :class:`GridEmulator` over its own rows with its own
    hyperparameters; with ``calibration.emulator.hyperparameters: per_output``
    a block is one output. One output's response can want short length-scales
    on a calibration input (heating on a leakage area) where another's wants
    long ones on everything but its loads (electricity); a shared kernel has
    to compromise, and the MLE can then park an input that plainly acts at
    its length-scale bound. Rows of different blocks are uncorrelated a
    priori, so the emulator's mean is each block's and its covariance is
    block-diagonal.

    Attributes
    ----------
    x : ndarray, shape (M, d_x)
        Standardised variable inputs of every row.
    blocks : tuple of GridEmulator
        Each block's emulator; its ``x`` holds the block's rows and the
        columns that vary over them.
    rows : tuple of ndarray
        Each block's rows, as indices into ``x``.
    columns : tuple of ndarray
        Each block's variable-input columns, as indices into ``x``'s columns.
    names : tuple of str
        Each block's name (its output, or ``all``).
    """

    x: np.ndarray
    blocks: tuple[GridEmulator, ...]
    rows: tuple[np.ndarray, ...]
    columns: tuple[np.ndarray, ...]
    names: tuple[str, ...]

    @property
    def t(self) -> np.ndarray:
        """Emulator inputs of the design runs, shape (R, k) (shared by the blocks)."""
        return self.blocks[0].t

    @property
    def inputs(self) -> ParameterInputs:
        """The map from prior-CDF values to ``t``."""
        return self.blocks[0].inputs

    @property
    def hypers(self) -> tuple[Hyperparameters, ...]:
        return tuple(block.hyper for block in self.blocks)

    def t_of_unit(self, unit: np.ndarray) -> np.ndarray:
        """Emulator inputs ``t`` of prior-CDF values ``(n, k)``."""
        return self.inputs.from_unit(unit)

    def block_of(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each of ``rows``' block and its position within the block."""
        block = np.empty(len(self.x), dtype=int)
        position = np.empty(len(self.x), dtype=int)
        for g, mine in enumerate(self.rows):
            block[mine], position[mine] = g, np.arange(len(mine))
        rows = np.asarray(rows, dtype=int)
        return block[rows], position[rows]

    def predict_mean(self, t_new: np.ndarray) -> np.ndarray:
        """Posterior mean at every row for each ``t_new`` (B, k) -> (B, M), standardised."""
        t_new = np.atleast_2d(t_new)
        mean = np.empty((len(t_new), len(self.x)))
        for block, mine in zip(self.blocks, self.rows):
            mean[:, mine] = block.predict_mean(t_new)
        return mean

    def predict_cov(self, t_new: np.ndarray) -> np.ndarray:
        """Posterior covariance over the rows at one ``t_new`` (k,) -> (M, M), block-diagonal."""
        cov = np.zeros((len(self.x), len(self.x)))
        for block, mine in zip(self.blocks, self.rows):
            cov[np.ix_(mine, mine)] = block.predict_cov(t_new)
        return cov


def block_emulator(x: np.ndarray, t: np.ndarray, y: np.ndarray,
                   hypers: tuple[Hyperparameters, ...], rows: tuple[np.ndarray, ...],
                   columns: tuple[np.ndarray, ...], names: tuple[str, ...],
                   inputs: ParameterInputs | None = None) -> BlockEmulator:
    """Condition each block's emulator on the runs ``t`` (R, k) and values ``y`` (R, M)."""
    blocks = tuple(GridEmulator(x[np.ix_(mine, cols)], t, y[:, mine], hyper, inputs)
                   for hyper, mine, cols in zip(hypers, rows, columns))
    return BlockEmulator(x=x, blocks=blocks, rows=rows, columns=columns, names=names)


@dataclass
class EmulatorTest:
    """Hold-out test of the emulator on whole runs (seed Figure 4.6).

    ``per_output[o]["mse_standardised"]`` is the emulator's squared error in
    standardised units, which the calibration adds to the observation
    error (the GP's own variance understates it).
    """

    r2: float
    rmse_standardised: float
    per_output: dict[str, dict[str, float]]
    test_runs: np.ndarray
    predicted: np.ndarray       # (test runs, M), output units
    simulated: np.ndarray       # (test runs, M), output units


def r_squared(observed: np.ndarray, predicted: np.ndarray) -> float:
    """Coefficient of determination ``1 - SS_res / SS_tot``."""
    observed, predicted = np.ravel(observed), np.ravel(predicted)
    total = np.sum((observed - observed.mean()) ** 2)
    return float(1.0 - np.sum((observed - predicted) ** 2) / total) if total > 0 else float("nan")


@dataclass
class Emulator:
    """The fitted emulator: scaling, hyperparameters, the grid conditional and its test."""

    scaling: Scaling
    grid: BlockEmulator
    test: EmulatorTest | None
    row_outputs: np.ndarray      # output name of each row (M,)
    fit_points: pd.DataFrame     # the (block, run, row) triples used for the MLE fits

    @property
    def hypers(self) -> tuple[Hyperparameters, ...]:
        """Each block's hyperparameters."""
        return self.grid.hypers


def fit_emulator(x: pd.DataFrame, row_outputs: pd.Series, simulated: np.ndarray,
                 unit: np.ndarray, points: int = 840, test_fraction: float = 0.1,
                 restarts: int = 1, random_state: int = 0,
                 inputs: ParameterInputs | None = None, per_output: bool = True,
                 grid_fit: bool = False) -> Emulator:
    """Fit and test the emulator on the simulations of every row.

    Parameters
    ----------
    x : DataFrame, shape (M, d_x)
        Variable inputs of the rows (calibration and held-out).
    row_outputs : Series, shape (M,)
        Output name of each row.
    simulated : ndarray, shape (M, R)
        Simulated values, output units.
    unit : ndarray, shape (R, k)
        Prior-CDF values of the runs' calibration parameters.
    points : int
        (run, row) pairs for the MLE fit of each block's hyperparameters.
    test_fraction : float
        Share of the runs held out to test the emulator (0: no test).
    inputs : ParameterInputs, optional
        How the calibration parameters enter the emulator (default: :func:`unit_inputs`).
    per_output : bool
        One block, with its own hyperparameters, per output (see
        :class:`BlockEmulator`); else one block over every row, the output
        type entering as a variable input.
    grid_fit : bool
        Refine each block's scattered-point fit on its whole training grid,
        with a row term (:func:`fit_grid_hyperparameters`).
    """
    rng = np.random.default_rng(random_state)
    inputs = inputs or unit_inputs(np.shape(unit)[1])
    scaling = make_scaling(x, row_outputs, simulated)
    xs = scaling.x(x)
    outputs = row_outputs.to_numpy()
    ys = scaling.y(simulated, outputs).T            # (R, M)
    ts = inputs.from_unit(unit)
    n_runs = len(ts)
    n_test = int(round(test_fraction * n_runs))
    order = rng.permutation(n_runs)
    test_runs, train_runs = np.sort(order[:n_test]), np.sort(order[n_test:])
    if per_output:
        names = scaling.outputs
        rows = tuple(np.flatnonzero(outputs == o) for o in names)
    else:
        names, rows = ("all",), (np.arange(len(xs)),)
    # a column constant over a block's rows (its output's indicator) has no length-scale
    columns = tuple(np.flatnonzero(np.ptp(xs[mine], axis=0) > 1e-12) for mine in rows)
    hypers, picks = [], []
    for g, (mine, cols) in enumerate(zip(rows, columns)):
        n_points = min(points, len(train_runs) * len(mine))
        flat = rng.choice(len(train_runs) * len(mine), n_points, replace=False)
        run_pick, row_pick = train_runs[flat // len(mine)], mine[flat % len(mine)]
        hyper = fit_hyperparameters(xs[np.ix_(row_pick, cols)], ts[run_pick],
                                    ys[run_pick, row_pick], restarts=restarts,
                                    random_state=random_state)
        if grid_fit:
            hyper = fit_grid_hyperparameters(xs[np.ix_(mine, cols)], ts[train_runs],
                                             ys[np.ix_(train_runs, mine)], hyper)
        hypers.append(hyper)
        picks.append(pd.DataFrame({"block": names[g], "run": run_pick, "row": row_pick}))
    test = None
    if n_test:
        trained = block_emulator(xs, ts[train_runs], ys[train_runs], tuple(hypers), rows,
                                 columns, names, inputs)
        predicted = trained.predict_mean(ts[test_runs])
        scores = {}
        pred_units = scaling.y_back(predicted, outputs)
        sim_units = simulated[:, test_runs].T
        for o in scaling.outputs:
            mine = outputs == o
            scores[o] = {
                "r2": r_squared(sim_units[:, mine], pred_units[:, mine]),
                "rmse": float(np.sqrt(np.mean((sim_units[:, mine] - pred_units[:, mine]) ** 2))),
                # R² of the runs' departures from the row mean: how well the
                # emulator predicts what the calibration parameters do
                "r2_parameter_effect": r_squared(
                    sim_units[:, mine] - sim_units[:, mine].mean(axis=0),
                    pred_units[:, mine] - sim_units[:, mine].mean(axis=0)),
                "mse_standardised": float(np.mean((ys[test_runs][:, mine]
                                                   - predicted[:, mine]) ** 2)),
            }
        test = EmulatorTest(r2=r_squared(ys[test_runs], predicted),
                            rmse_standardised=float(
                                np.sqrt(np.mean((ys[test_runs] - predicted) ** 2))),
                            per_output=scores, test_runs=test_runs, predicted=pred_units,
                            simulated=sim_units)
    grid = block_emulator(xs, ts, ys, tuple(hypers), rows, columns, names, inputs)
    return Emulator(scaling=scaling, grid=grid, test=test, row_outputs=outputs,
                    fit_points=pd.concat(picks, ignore_index=True))


def parameter_effects(grid: BlockEmulator, rows: np.ndarray, levels: int = 9, bases: int = 64,
                      random_state: int = 0) -> np.ndarray:
    """Largest main effect of each calibration parameter on the emulator mean (standardised).

    For ``bases`` design points, one parameter sweeps ``levels`` values over
    its range (others held); the effect is the root mean square over
    ``rows`` of the sweep's range, averaged over the base points.
    """
    rng = np.random.default_rng(random_state)
    base = grid.t[rng.choice(len(grid.t), min(bases, len(grid.t)), replace=False)]
    sweep = np.linspace(0.02, 0.98, levels)
    effects = np.empty(grid.t.shape[1])
    for k in range(grid.t.shape[1]):
        points = np.repeat(base, levels, axis=0)
        points[:, k] = np.tile(grid.inputs.column(k, sweep), len(base))
        mean = grid.predict_mean(points)[:, rows].reshape(len(base), levels, -1)
        spread = mean.max(axis=1) - mean.min(axis=1)
        effects[k] = float(np.mean(np.sqrt(np.mean(spread ** 2, axis=1))))
    return effects
