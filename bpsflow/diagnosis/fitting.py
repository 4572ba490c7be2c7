"""Fitting parameters to one measured hourly output, on either backend, and scoring the fit.

The objective is the deterministic calibration's (seed §4.3.5, eq. 1–2):
``w₁·NMBE² + w₂·CV(RMSE)²`` on the calibration hours, written as a sum of
squares so that a Levenberg–Marquardt solver can use its structure: the
residual vector is the hourly errors over ``ȳ·√n`` plus one term
``√(w₁/w₂)·mean error / ȳ``. Gauss–Newton steps need a handful of Jacobians
where a quasi-Newton method on the scalar objective needs dozens, which
matters when every point is a simulation. The solver is written here (not
``scipy.optimize.least_squares``) because it advances many fits in lockstep
so that each iteration is one batch of simulations (:func:`fit_many`).

Parameters are searched on ``[0, 1]`` over their range (uniform bounds, or
the 0.5–99.5 % quantiles of other distributions). The Jacobian is a forward
difference whose points run as one batch (one vectorised surrogate call, or
parallel EnergyPlus runs).

The fitted model's predictive distribution (for nMCRPS, seed eq. 7) is the
linearised one: ``ŷ + J·δθ + ε`` with ``δθ ~ N(0, s²(JᵀJ)⁻¹)`` from the
calibration hours and ``ε ~ N(0, s²)``, so it costs no extra simulation.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, Parameter
from bpsflow.distributions import Uniform
from bpsflow.metrics import cv_rmse, guideline14_check, nmbe, nmcrps

#: Predicts the output at every hour for a batch of samples: DataFrame (B rows) -> (B, n).
Simulator = Callable[[pd.DataFrame], np.ndarray]

_STEP = 1e-3


def parameter_range(parameter: Parameter) -> tuple[float, float]:
    """The search range of a fitted parameter (its bounds, or 0.5–99.5 % quantiles)."""
    distribution = parameter.distribution
    if isinstance(distribution, Uniform):
        return float(distribution.lower), float(distribution.upper)
    return float(distribution.ppf(np.array([0.005]))[0]), float(distribution.ppf(np.array([0.995]))[0])


def output_simulator(config: Config, output: str, timestamps: pd.DatetimeIndex, *,
                     backend: str, work_dir: Path, jobs: int | None = None,
                     sequences_dir: Path | None = None, on_failure: str = "raise") -> Simulator:
    """A :data:`Simulator` of ``output`` at ``timestamps`` (hour-ending) on ``backend``.

    The surrogate runs a batch in one vectorised call, reading the boundary
    sequences from ``sequences_dir`` (default ``work_dir``; drawn there once,
    so simulators that share it do not draw them again). EnergyPlus runs
    each batch in a fresh run directory under ``work_dir`` (in parallel,
    ``jobs``).

    ``on_failure``: ``"raise"`` (a failed instance raises
    :class:`~bpsflow.simulation.ensemble.BatchFailure`) or ``"record"``: a
    failed instance's row is NaN and its error is in the simulator's
    ``failures`` (row position -> error excerpt, for the last batch; see
    :class:`OutputSimulator`).
    """
    if on_failure not in ("raise", "record"):
        raise ValueError(f"on_failure: expected 'raise' or 'record', got {on_failure!r}")
    return OutputSimulator(config, output, timestamps, backend=backend, work_dir=Path(work_dir),
                           jobs=jobs, sequences_dir=sequences_dir,
                           record=on_failure == "record")


class OutputSimulator:
    """A :data:`Simulator` of one output on one backend (made by :func:`output_simulator`).

    The failure signal, when ``record`` is on: a row of NaN in the returned
    matrix, and ``failures[row position] = error excerpt`` for the last call
    (:func:`fit_many` and :func:`bpsflow.diagnosis.signatures.signatures` read
    both; any :data:`Simulator` may signal a failure by a NaN row alone).
    """

    def __init__(self, config: Config, output: str, timestamps: pd.DatetimeIndex, *,
                 backend: str, work_dir: Path, jobs: int | None, sequences_dir: Path | None,
                 record: bool):
        from bpsflow.simulation.backend import get_backend

        self.config, self.output, self.timestamps = config, output, timestamps
        self.backend = get_backend(backend)
        self.work_dir, self.jobs = Path(work_dir), jobs
        self.sequences_dir = Path(sequences_dir or work_dir)
        self.record = record
        self.calls = 0
        self.failures: dict[int, str] = {}
        self._model_digest: str | None = None

    def to_matrix(self, tidy: pd.DataFrame, labels: list) -> np.ndarray:
        output, timestamps = self.output, self.timestamps
        mine = tidy[tidy["output"] == output].drop_duplicates(["instance", "timestamp"])
        if not len(mine):
            return np.full((len(labels), len(timestamps)), np.nan)
        wide = mine.pivot(index="instance", columns="timestamp", values="value")
        wide.columns = pd.DatetimeIndex(wide.columns)
        missing = timestamps.difference(wide.columns)
        if len(missing):
            raise ValueError(f"the model does not simulate {output} at {len(missing)} measured "
                             f"hour(s), first {missing[0]}")
        return wide.reindex(index=labels, columns=timestamps).to_numpy(dtype=float)

    def __call__(self, samples: pd.DataFrame) -> np.ndarray:
        if self.backend.vectorised:
            return self._simulate(samples)
        return self._resumable(samples)

    def _simulate(self, samples: pd.DataFrame) -> np.ndarray:
        from bpsflow.simulation.ensemble import simulate_batch, simulate_samples

        self.calls += 1
        # A vectorised backend simulates in this process and shares one folder of
        # boundary sequences; another runs each batch in a fresh folder.
        workdir = self.work_dir / f"batch_{self.calls:03d}"
        if not self.record:
            tidy = simulate_samples(self.config, samples, workdir, self.backend, jobs=self.jobs,
                                    sequences_dir=self.sequences_dir)
            return self.to_matrix(tidy, list(samples.index))
        outcome = simulate_batch(self.config, samples, workdir, self.backend, jobs=self.jobs,
                                 sequences_dir=self.sequences_dir)
        labels = list(samples.index)
        matrix = np.array(self.to_matrix(outcome.tidy, labels), dtype=float)  # writable
        self.failures = {row: outcome.failed[int(label)] for row, label in enumerate(labels)
                         if int(label) in outcome.failed}
        for row in self.failures:
            matrix[row] = np.nan
        return matrix

    def _digest(self) -> str:
        """The run cache's digest of this simulator's model and inputs, made once.

        A simulator's config and files do not change while it is used (each
        stage of a diagnosis makes its own).
        """
        if self._model_digest is None:
            from bpsflow.boundary import ensure_sequences
            from bpsflow.simulation import rundir
            from bpsflow.simulation.ensemble import run_config
            from bpsflow.simulation.run_cache import model_digest

            # the sequences are part of the key: draw them before the digest
            rundir.prepare_run_dir(self.sequences_dir)
            ensure_sequences(run_config(self.config, self.sequences_dir))
            self._model_digest = model_digest(self.config, self.backend.name,
                                              self.sequences_dir)
        return self._model_digest

    def _resumable(self, samples: pd.DataFrame) -> np.ndarray:
        """:meth:`_simulate` for the rows not already in the run cache (slow backends only).

        Every finished row is stored (:mod:`bpsflow.simulation.run_cache`), so the
        same command run again after a stop simulates only what it had not
        finished. Failed rows are not stored and run again.
        """
        from bpsflow.simulation.run_cache import RunCache

        cache = RunCache(self.sequences_dir / "cache")
        values = samples.drop(columns=["instance"], errors="ignore")
        keys = cache.keys(self._digest(), self.output, self.timestamps, values)
        matrix = np.full((len(samples), len(self.timestamps)), np.nan)
        missing = []
        for row, key in enumerate(keys):
            stored = cache.get(key, len(self.timestamps))
            if stored is None:
                missing.append(row)
            else:
                matrix[row] = stored
        failures: dict[int, str] = {}
        if missing:
            self.failures = {}
            ran = self._simulate(samples.iloc[missing])
            failures = {missing[row]: error for row, error in self.failures.items()}
            for row, output in zip(missing, ran):
                matrix[row] = output
                if row not in failures and np.isfinite(output).all():
                    cache.put(keys[row], output)
        self.failures = failures
        return matrix


@dataclass
class Fit:
    """A least-squares fit of ``parameters`` (values in their units) and its linearisation."""

    parameters: list[Parameter]
    values: np.ndarray            # (k,) fitted values
    prediction: np.ndarray        # (n,) at every hour (calibration and held-out)
    jacobian: np.ndarray          # (n, k) d prediction / d value
    covariance: np.ndarray        # (k, k) of the values (linearised)
    residual_std: float           # s, output units, calibration hours
    objective: float              # NMBE² + CV(RMSE)² on the calibration hours
    evaluations: int              # simulated instances (of the whole batch it ran in)
    seconds: float
    iterations: int = 0
    failure: str = ""             # why the problem failed (its starting point did not run)
    failed_trials: list[str] = field(default_factory=list)  # trial points that did not run

    @property
    def failed(self) -> bool:
        return bool(self.failure)

    @property
    def named(self) -> dict[str, float]:
        return {p.name: float(v) for p, v in zip(self.parameters, self.values)}


@dataclass
class Problem:
    """One fit: the parameters to fit, the fixed values of the others, and the data.

    ``measured`` covers every hour; ``calibration`` (bool) marks the hours fitted.
    ``start`` holds starting values of (some of) the fitted parameters
    (default: their nominal values).
    """

    base_sample: dict[str, float]
    parameters: list[Parameter]
    measured: np.ndarray
    calibration: np.ndarray
    start: dict[str, float] | None = None
    nmbe_weight: float = 1.0


def fit_many(simulate: Simulator, problems: list[Problem], *, max_iterations: int = 20,
             tolerance: float = 1e-4, jacobian_on_acceptance: bool = False) -> list[Fit]:
    """Fit several problems at once with a bounded Levenberg–Marquardt, one batch per iteration.

    Every iteration simulates, for every unfinished problem, its trial point
    and that point's ``k`` forward-difference neighbours, all in ONE call of
    ``simulate``: the surrogate's cost per call is mostly fixed (its time
    stepping), so several fits (candidate extensions, repeated datasets) cost
    about as much as one. Bounds: the search runs on ``[0, 1]`` per parameter;
    a parameter at a bound whose step points outwards is held there for that
    step (projected Levenberg–Marquardt). A problem stops when its objective
    decreases by less than ``tolerance`` (relative) or its step is below
    ``1e-5`` of the range.

    A point that does not run (a NaN row from ``simulate``, with the error in
    ``simulate.failures`` when it has one, see
    :class:`OutputSimulator`) never aborts the batch: a failed trial point
    (or one of its difference neighbours) is a rejected step (infinite cost,
    more damping), and a problem whose starting point fails ends as failed
    (:attr:`Fit.failure`, prediction NaN) while the others go on.

    ``jacobian_on_acceptance``: run each iteration's trial points first and the
    difference neighbours of the accepted ones only, in a second batch. A
    rejected step's neighbours are never used, so the fits are the same; on a
    backend that pays per run (EnergyPlus) each rejected step saves ``k`` runs,
    on one that pays per call (the vectorised surrogate) the second call costs
    more than it saves.
    """
    started = time.perf_counter()
    states = [_State(p) for p in problems]
    count = 0

    def evaluate(requests: list[tuple[_State, np.ndarray]], *, trial: bool = True,
                 neighbours: bool = True) -> list[tuple[list[np.ndarray], str]]:
        nonlocal count
        rows, spans = [], []
        for state, x in requests:
            points = ([x] if trial else []) + (state.neighbours(x) if neighbours else [])
            spans.append(len(points))
            rows += [state.sample(point) for point in points]
        samples = pd.DataFrame(rows, index=pd.RangeIndex(len(rows), name="instance"))
        predicted = simulate(samples) if rows else np.zeros((0, 0))
        errors = getattr(simulate, "failures", None) or {}
        count += len(rows)
        out, first = [], 0
        for (state, _), size in zip(requests, spans):
            block = predicted[first:first + size]
            bad = [first + i for i in range(size)
                   if not np.isfinite(block[i][state.mask]).all()]
            error = "" if not bad else (errors.get(bad[0]) or "non-finite output")
            out.append((list(block), error))
            first += size
        return out

    for state, (result, error) in zip(states, evaluate([(s, s.x) for s in states])):
        if error:
            state.fail(f"its starting point did not run: {error}")
        else:
            state.take(state.x, result)
    for _ in range(max_iterations):
        active = [s for s in states if not s.done]
        if not active:
            break
        trials = [(s, s.trial()) for s in active]
        if not jacobian_on_acceptance:
            for (state, x), (result, error) in zip(trials, evaluate(trials)):
                state.judge(x, result, tolerance, error)
            continue
        accepted = []
        for (state, x), (result, error) in zip(trials, evaluate(trials, neighbours=False)):
            if not error and state.lowers_cost(result[0]):
                accepted.append((state, x, result[0]))
            else:
                state.judge(x, result, tolerance, error)
        jacobians = evaluate([(state, x) for state, x, _ in accepted], trial=False)
        for (state, x, prediction), (result, error) in zip(accepted, jacobians):
            state.judge(x, [prediction, *result], tolerance, error)
    seconds = time.perf_counter() - started
    return [s.fit(count, seconds) for s in states]


class _State:
    """One problem's Levenberg–Marquardt state (unit-cube coordinates)."""

    def __init__(self, problem: Problem):
        self.problem = problem
        bounds = np.array([parameter_range(p) for p in problem.parameters]).reshape(-1, 2)
        self.lower, self.width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
        self.names = [p.name for p in problem.parameters]
        self.k = len(self.names)
        self.y = np.asarray(problem.measured, dtype=float)
        self.mask = np.asarray(problem.calibration, dtype=bool)
        mean = float(np.mean(self.y[self.mask]))
        self.mean = mean if abs(mean) > 1e-12 else 1.0
        self.n_cal = int(self.mask.sum())
        x0 = np.full(self.k, 0.5)
        for j, p in enumerate(problem.parameters):
            value = (problem.start or {}).get(p.name, p.distribution.nominal)
            x0[j] = np.clip((float(value) - self.lower[j]) / self.width[j], 0.0, 1.0)
        self.x = x0
        self.damping = 1e-3
        self.done = self.k == 0
        self.iterations = 0
        self.failure = ""
        self.failed_trials: list[str] = []

    def values(self, x: np.ndarray) -> np.ndarray:
        return self.lower + np.clip(x, 0.0, 1.0) * self.width

    def sample(self, x: np.ndarray) -> dict[str, float]:
        row = dict(self.problem.base_sample)
        row.update(zip(self.names, self.values(x)))
        return row

    def steps(self, x: np.ndarray) -> np.ndarray:
        return np.where(x + _STEP <= 1.0, _STEP, -_STEP)

    def neighbours(self, x: np.ndarray) -> list[np.ndarray]:
        steps = self.steps(x)
        return [x + np.eye(self.k)[j] * steps[j] for j in range(self.k)]

    def residuals(self, prediction: np.ndarray) -> np.ndarray:
        error = self.y[self.mask] - prediction[self.mask]
        return np.concatenate([error / (self.mean * np.sqrt(self.n_cal)),
                               [np.sqrt(self.problem.nmbe_weight) * np.mean(error) / self.mean]])

    def take(self, x: np.ndarray, predictions: list[np.ndarray]) -> None:
        """Make ``x`` the current point, with its prediction and Jacobian."""
        self.x = x
        self.prediction = predictions[0]
        self.r = self.residuals(self.prediction)
        self.cost = float(self.r @ self.r)
        steps = self.steps(x)
        self.neighbour_predictions = predictions[1:]
        self.J = np.column_stack([(self.residuals(p) - self.r) / steps[j]
                                  for j, p in enumerate(predictions[1:])]) \
            if self.k else np.zeros((len(self.r), 0))

    def _step(self, damping: float) -> np.ndarray:
        free = np.ones(self.k, dtype=bool)
        gradient = self.J.T @ self.r
        for _ in range(self.k + 1):
            J = self.J[:, free]
            normal = J.T @ J
            step = np.zeros(self.k)
            step[free] = np.linalg.lstsq(normal + damping * np.diag(np.diag(normal) + 1e-12),
                                         -gradient[free], rcond=None)[0]
            outwards = free & (((self.x <= 0.0) & (step < 0)) | ((self.x >= 1.0) & (step > 0)))
            if not outwards.any():
                break
            free &= ~outwards
        return step

    def trial(self) -> np.ndarray:
        step = self._step(self.damping)
        self.last_step = step
        return np.clip(self.x + step, 0.0, 1.0)

    def _converged(self, tolerance: float) -> bool:
        """True when even an undamped step promises less than the tolerance.

        A small decrease after a heavily damped (short) step says little: in a
        long curved valley (an internal mass's area against its thickness) the
        fit would stop far from the minimum. The Gauss–Newton model's own
        promise is the test (Moré 1978's predicted reduction).
        """
        step = np.clip(self.x + self._step(1e-9), 0.0, 1.0) - self.x
        promised = self.r @ self.r - float(np.sum((self.r + self.J @ step) ** 2))
        return promised < tolerance * max(self.cost, 1e-300)

    def fail(self, reason: str) -> None:
        """End this problem as failed (its starting point did not run)."""
        self.failure = reason
        self.done = True
        self.prediction = np.full(len(self.y), np.nan)
        self.neighbour_predictions = [self.prediction] * self.k
        self.cost = float("inf")

    def lowers_cost(self, prediction: np.ndarray) -> bool:
        """True when a trial point's prediction is accepted by :meth:`judge` (a lower cost)."""
        r = self.residuals(prediction)
        return float(r @ r) < self.cost

    def judge(self, x: np.ndarray, predictions: list[np.ndarray], tolerance: float,
              error: str = "") -> None:
        self.iterations += 1
        moved = float(np.max(np.abs(x - self.x))) if self.k else 0.0
        if error:  # a point that did not run is a rejected step, never the end of the batch
            self.failed_trials.append(error)
            cost = float("inf")
        else:
            r = self.residuals(predictions[0])
            cost = float(r @ r)
        if cost < self.cost:
            decrease = (self.cost - cost) / max(self.cost, 1e-300)
            self.take(x, predictions)
            self.damping = max(self.damping / 5, 1e-9)
            if moved < 1e-5 or (decrease < tolerance and self._converged(tolerance)):
                self.done = True
        else:
            self.damping *= 10
            if self.damping > 1e8 or moved < 1e-5:
                self.done = True

    def fit(self, evaluations: int, seconds: float) -> Fit:
        steps = self.steps(self.x)
        jac = np.column_stack([(p - self.prediction) / (steps[j] * self.width[j])
                               for j, p in enumerate(self.neighbour_predictions)]) \
            if self.k else np.zeros((len(self.y), 0))
        error = self.y[self.mask] - self.prediction[self.mask]
        residual_std = float(np.sqrt(np.sum(error ** 2) / max(self.n_cal - self.k, 1)))
        j_cal = jac[self.mask]
        if self.failure:
            covariance = np.full((self.k, self.k), np.nan)
        else:
            covariance = residual_std ** 2 * np.linalg.pinv(j_cal.T @ j_cal) if self.k \
                else np.zeros((0, 0))
        return Fit(parameters=list(self.problem.parameters), values=self.values(self.x),
                   prediction=self.prediction, jacobian=jac, covariance=covariance,
                   residual_std=residual_std, objective=self.cost, evaluations=evaluations,
                   seconds=seconds, iterations=self.iterations, failure=self.failure,
                   failed_trials=list(self.failed_trials))


def predictive_ensemble(fit: Fit, size: int, random_state: int = 0) -> np.ndarray:
    """Linearised predictive ensemble ``(n, size)`` of the fitted model (see module notes)."""
    rng = np.random.default_rng(random_state)
    k = len(fit.values)
    shifts = rng.multivariate_normal(np.zeros(k), fit.covariance, size=size,
                                     method="eigh") if k else np.zeros((size, 0))
    members = fit.prediction[:, None] + fit.jacobian @ shifts.T
    return members + rng.standard_normal(members.shape) * fit.residual_std


def scores(measured: np.ndarray, prediction: np.ndarray, ensemble: np.ndarray) -> dict:
    """NMBE, CV(RMSE), nMCRPS (fractions) and ASHRAE Guideline 14 (hourly) of one block."""
    bias = float(nmbe(measured, prediction))
    spread = float(cv_rmse(measured, prediction))
    check = guideline14_check(bias, spread, "hourly")
    return {"nmbe": bias, "cvrmse": spread, "nmcrps": float(nmcrps(measured, ensemble)),
            "guideline14": bool(check.passed), "hours": int(len(measured))}
