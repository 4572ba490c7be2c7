"""Probability distributions of uncertain inputs, as validated config objects.

Each distribution maps a unit-interval design value ``u`` (from a Latin
hypercube or a Morris grid) to a parameter value through its inverse CDF
(:meth:`ppf`), so that one design drives every marginal (seed §3.4: bounded
normal for material properties, Table 3.1; uniform for ground reflectance and
stratification; U(0,1) *samplers* that select one of N pre-drawn boundary
temperature sequences, §3.4.5).

The ``type`` key selects the distribution in YAML::

    distribution: {type: normal, mean: 1.0, std: 0.05, lower: 0.85, upper: 1.15}
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from bpsflow.schema import StrictModel


def _stats():
    """``scipy.stats``, imported on first use: loading a config (in every worker) does not pay
    for it."""
    from scipy import stats

    return stats


def _standard_normal_cdf(z: float) -> float:
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


class _Distribution(StrictModel):
    model_config = ConfigDict(frozen=True)

    def ppf(self, u: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def scipy(self):  # pragma: no cover - abstract
        """The equivalent frozen ``scipy.stats`` distribution (for tests, KS checks)."""
        raise NotImplementedError

    @property
    def nominal(self) -> float:
        """A central value (the median), used when a parameter is held fixed."""
        return float(self.ppf(np.array([0.5]))[0])


class Uniform(_Distribution):
    """Uniform on [lower, upper]."""

    type: Literal["uniform"]
    lower: float
    upper: float

    @model_validator(mode="after")
    def _check(self) -> Uniform:
        if not self.upper > self.lower:
            raise ValueError(f"upper ({self.upper}) must be greater than lower ({self.lower})")
        return self

    def scipy(self):
        return _stats().uniform(loc=self.lower, scale=self.upper - self.lower)

    def ppf(self, u: np.ndarray) -> np.ndarray:
        return self.lower + np.asarray(u, dtype=float) * (self.upper - self.lower)


class Normal(_Distribution):
    """Normal(mean, std), truncated to [lower, upper] when bounds are given.

    Seed §3.4.1 uses bounded normals for material properties with the relative
    standard deviations of Table 3.1.
    """

    type: Literal["normal"]
    mean: float
    std: float = Field(gt=0)
    lower: float | None = None
    upper: float | None = None

    @model_validator(mode="after")
    def _check(self) -> Normal:
        lo = -np.inf if self.lower is None else self.lower
        hi = np.inf if self.upper is None else self.upper
        if not hi > lo:
            raise ValueError(f"upper ({self.upper}) must be greater than lower ({self.lower})")
        a, b = self._standard_bounds()
        if _standard_normal_cdf(b) - _standard_normal_cdf(a) < 1e-12:
            raise ValueError(
                f"the bounds [{self.lower}, {self.upper}] hold no probability mass of "
                f"Normal(mean={self.mean}, std={self.std})"
            )
        return self

    def _standard_bounds(self) -> tuple[float, float]:
        """The bounds in standard deviations from the mean (±inf where there is none)."""
        lo = -np.inf if self.lower is None else self.lower
        hi = np.inf if self.upper is None else self.upper
        return (lo - self.mean) / self.std, (hi - self.mean) / self.std

    def scipy(self):
        a, b = self._standard_bounds()
        return _stats().truncnorm(a, b, loc=self.mean, scale=self.std)

    def ppf(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        a, b = self._standard_bounds()
        if a <= 1.0 and b >= -1.0:
            # Bounds around the centre: the inverse CDF of the truncated normal directly
            # (agrees with scipy's truncnorm to ~1e-15 inside, ~1e-9 at the 1e-9 tails;
            # scipy.special loads in a third of scipy.stats' time, which every command
            # would pay to check bounds)
            from scipy.special import ndtr, ndtri

            low, high = ndtr(a), ndtr(b)
            upper_low, upper_high = ndtr(-b), ndtr(-a)  # the upper half from its own tail
            z = np.where(u <= 0.5, ndtri(low + u * (high - low)),
                         -ndtri(upper_low + (1.0 - u) * (upper_high - upper_low)))
            return self.mean + self.std * z
        return self.scipy().ppf(u)


class Beta(_Distribution):
    """Scaled beta: ``Beta(a, b) * scale + shift``."""

    type: Literal["beta"]
    a: float = Field(gt=0)
    b: float = Field(gt=0)
    scale: float = Field(default=1.0, gt=0)
    shift: float = 0.0

    def scipy(self):
        return _stats().beta(self.a, self.b, loc=self.shift, scale=self.scale)

    def ppf(self, u: np.ndarray) -> np.ndarray:
        return self.scipy().ppf(np.asarray(u, dtype=float))


class LogNormal(_Distribution):
    """Lognormal: ``log X ~ Normal(mu, sigma)`` (``mu`` and ``sigma`` of the log)."""

    type: Literal["lognormal"]
    mu: float
    sigma: float = Field(gt=0)

    def scipy(self):
        return _stats().lognorm(s=self.sigma, scale=float(np.exp(self.mu)))

    def ppf(self, u: np.ndarray) -> np.ndarray:
        return self.scipy().ppf(np.asarray(u, dtype=float))


class Triangular(_Distribution):
    """Triangular on [lower, upper] with its peak at ``mode``."""

    type: Literal["triangular"]
    lower: float
    mode: float
    upper: float

    @model_validator(mode="after")
    def _check(self) -> Triangular:
        if not (self.lower <= self.mode <= self.upper and self.upper > self.lower):
            raise ValueError(
                f"expected lower <= mode <= upper with lower < upper, got "
                f"{self.lower}, {self.mode}, {self.upper}"
            )
        return self

    def scipy(self):
        width = self.upper - self.lower
        return _stats().triang((self.mode - self.lower) / width, loc=self.lower, scale=width)

    def ppf(self, u: np.ndarray) -> np.ndarray:
        return self.scipy().ppf(np.asarray(u, dtype=float))


class Discrete(_Distribution):
    """A finite set of values with optional weights (equal by default)."""

    type: Literal["discrete"]
    values: list[float] = Field(min_length=1)
    weights: list[float] | None = None

    @model_validator(mode="after")
    def _check(self) -> Discrete:
        if self.weights is not None:
            if len(self.weights) != len(self.values):
                raise ValueError(
                    f"weights has {len(self.weights)} entries but values has {len(self.values)}"
                )
            if any(w < 0 for w in self.weights) or sum(self.weights) <= 0:
                raise ValueError("weights must be non-negative and sum to a positive number")
        return self

    def _probabilities(self) -> np.ndarray:
        weights = np.ones(len(self.values)) if self.weights is None else np.asarray(self.weights)
        return weights / weights.sum()

    def scipy(self):
        return _stats().rv_discrete(values=(np.asarray(self.values), self._probabilities()))

    def ppf(self, u: np.ndarray) -> np.ndarray:
        order = np.argsort(self.values)
        values = np.asarray(self.values, dtype=float)[order]
        cdf = np.cumsum(self._probabilities()[order])
        index = np.searchsorted(cdf, np.asarray(u, dtype=float), side="left")
        return values[np.clip(index, 0, len(values) - 1)]


class Empirical(_Distribution):
    """Values read from a file (one number per line, or a CSV column).

    Sampling uses the empirical quantile function (type 1, inverse of the
    step CDF), so each draw is one of the observed values.
    """

    type: Literal["empirical"]
    file: Path
    column: str | None = None
    values_: tuple[float, ...] = Field(default=(), exclude=True)

    def load(self, base_dir: Path) -> Empirical:
        """Return a copy with the values read from ``file`` (relative to ``base_dir``)."""
        import pandas as pd

        from bpsflow.errors import BpsflowError

        path = self.file if self.file.is_absolute() else base_dir / self.file
        if not path.is_file():
            raise BpsflowError(f"empirical distribution file not found: {path}")
        try:
            if self.column is None:
                values = np.loadtxt(path, dtype=float, ndmin=1)
            else:
                values = pd.read_csv(path)[self.column].to_numpy(dtype=float)
        except KeyError:
            raise BpsflowError(f"column '{self.column}' not in the file", source=path) from None
        except ValueError as exc:
            raise BpsflowError(f"expected numbers only: {exc}", source=path) from None
        values = values[np.isfinite(values)]
        if values.size == 0:
            raise BpsflowError("the empirical distribution file holds no finite values", source=path)
        return self.model_copy(update={"file": path, "values_": tuple(np.sort(values))})

    def scipy(self):
        support, counts = np.unique(self.values_, return_counts=True)
        return _stats().rv_discrete(values=(support, counts / counts.sum()))

    def ppf(self, u: np.ndarray) -> np.ndarray:
        values = np.asarray(self.values_, dtype=float)
        if values.size == 0:
            raise RuntimeError("Empirical.load() must be called before sampling")
        index = np.ceil(np.asarray(u, dtype=float) * values.size).astype(int) - 1
        return values[np.clip(index, 0, values.size - 1)]


class Sampler(_Distribution):
    """A U(0,1) sampler that selects one of ``sequences`` pre-drawn sequences.

    Seed §3.4.5: "a random sample is drawn from a (0,1) uniform distribution to
    determine the sequence to be used as the temperature boundary condition in
    each simulation instance". The sampled value is the sequence index
    ``floor(u * sequences)`` in 0..sequences-1.
    """

    type: Literal["sampler"]
    sequences: int = Field(ge=1)

    def scipy(self):
        return _stats().randint(0, self.sequences)

    def ppf(self, u: np.ndarray) -> np.ndarray:
        index = np.floor(np.asarray(u, dtype=float) * self.sequences)
        return np.clip(index, 0, self.sequences - 1)


class Constant(_Distribution):
    """A parameter held fixed at ``value`` (e.g. screened out by Morris, seed §3.4.8).

    Every draw returns ``value``; a constant parameter keeps its targets and its
    place in the design, so a reduced config still writes the same fields.
    """

    type: Literal["constant"]
    value: float

    def scipy(self):
        return _stats().rv_discrete(values=([self.value], [1.0]))

    def ppf(self, u: np.ndarray) -> np.ndarray:
        return np.full(np.shape(u), self.value, dtype=float)


Distribution = Annotated[
    Uniform | Normal | Beta | LogNormal | Triangular | Discrete | Empirical | Sampler | Constant,
    Field(discriminator="type"),
]


def truncation_notes(parameters: Sequence) -> list[str]:
    """A note per truncated normal whose mean lies outside its own bounds.

    Valid (the bounds hold probability mass) but rarely meant: the draws are
    one tail, piled up at the bound nearest the mean, and the ``mean`` key no
    longer says where they are.
    """
    notes = []
    for index, parameter in enumerate(parameters):
        d = parameter.distribution
        if not isinstance(d, Normal):
            continue
        below = d.lower is not None and d.mean < d.lower
        above = d.upper is not None and d.mean > d.upper
        if below or above:
            median = float(d.ppf(np.array([0.5]))[0])
            notes.append(f"parameters[{index}] ({parameter.name}): the normal's mean {d.mean:g} "
                         f"is {'below' if below else 'above'} its bounds [{d.lower}, {d.upper}]: "
                         f"the draws are one tail of it, piled at "
                         f"{d.lower if below else d.upper} (median {median:.4g})")
    return notes

