"""Designs over the uncertain inputs: Latin hypercube and Morris (via SALib).

A design is first drawn on the unit hypercube and then transformed through
each parameter's inverse CDF (:meth:`bpsflow.distributions._Distribution.ppf`),
so the same code serves every marginal. ``samples.parquet`` holds one row per
instance: ``instance`` (int) and one column per parameter (sampled value).
The unit design is kept beside it (``design_unit.parquet``) because Morris
analysis needs the grid steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bpsflow.config import Config, Parameter
from bpsflow.errors import BpsflowError
from bpsflow.files import read_parquet, write_parquet

SAMPLES_FILE = "samples.parquet"
UNIT_DESIGN_FILE = "design_unit.parquet"

#: How close to 0 and 1 a design's unit values come: ppf(0) and ppf(1) are infinite for
#: unbounded marginals, so ppf(UNIT_EPS) and ppf(1 - UNIT_EPS) are the most a design draws.
UNIT_EPS = 1e-12


@dataclass(frozen=True)
class Design:
    """A sampled design: unit-cube values and transformed parameter values."""

    unit: pd.DataFrame
    values: pd.DataFrame
    method: str


def _problem(parameters: list[Parameter]) -> dict:
    return {
        "num_vars": len(parameters),
        "names": [p.name for p in parameters],
        "bounds": [[0.0, 1.0]] * len(parameters),
    }


def latin_hypercube_unit(n_samples: int, n_parameters: int, random_state: int) -> np.ndarray:
    """A Latin hypercube of ``n_samples`` points in the open unit cube (SALib)."""
    problem = {"num_vars": n_parameters, "names": [f"x{i}" for i in range(n_parameters)],
               "bounds": [[0.0, 1.0]] * n_parameters}
    from SALib.sample import latin as salib_latin  # on first use: reading samples needs no SALib

    unit = salib_latin.sample(problem, n_samples, seed=random_state)
    return np.clip(unit, UNIT_EPS, 1 - UNIT_EPS)


def morris_unit(parameters: list[Parameter], trajectories: int, levels: int,
                random_state: int) -> np.ndarray:
    """A Morris design of ``trajectories * (k + 1)`` points (SALib), on level mid-points.

    SALib's grid spans [0, 1] inclusive; mapping level ``j`` of ``levels`` to
    ``(j + 0.5) / levels`` keeps every point inside the open interval so that
    unbounded marginals stay finite, while each Morris step is still a whole
    number of levels (seed §3.4.8: a 10-level design).
    """
    from SALib.sample import morris as salib_morris

    unit = salib_morris.sample(_problem(parameters), N=trajectories, num_levels=levels,
                               seed=random_state)
    level = np.rint(unit * (levels - 1))
    return (level + 0.5) / levels


def transform(unit: np.ndarray, parameters: list[Parameter]) -> np.ndarray:
    """Map unit-cube design values to parameter values through each inverse CDF."""
    values = np.empty_like(unit, dtype=float)
    for column, parameter in enumerate(parameters):
        values[:, column] = parameter.distribution.ppf(unit[:, column])
    return values


def sample(config: Config) -> Design:
    """Draw the config's design (LHS or Morris) and transform it.

    Returns
    -------
    Design
        ``unit`` and ``values`` share the ``instance`` index 0..n-1.
    """
    parameters = config.parameters
    if not parameters:
        raise BpsflowError("parameters: the config has no uncertain parameters to sample",
                           source=config.source)
    design = config.design
    if design.method == "lhs":
        unit = latin_hypercube_unit(design.samples, len(parameters), design.seed)
    else:
        unit = morris_unit(parameters, design.trajectories, design.levels, design.seed)
    names = [p.name for p in parameters]
    index = pd.RangeIndex(len(unit), name="instance")
    unit_frame = pd.DataFrame(unit, columns=names, index=index)
    values_frame = pd.DataFrame(transform(unit, parameters), columns=names, index=index)
    return Design(unit=unit_frame, values=values_frame, method=design.method)


def write_design(design: Design, run_dir: Path) -> Path:
    """Write ``samples.parquet`` and ``design_unit.parquet`` into ``run_dir``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    write_parquet(design.values.reset_index(), run_dir / SAMPLES_FILE, index=False)
    write_parquet(design.unit.reset_index(), run_dir / UNIT_DESIGN_FILE, index=False)
    return run_dir / SAMPLES_FILE


def read_samples(run_dir: Path) -> pd.DataFrame:
    """Read ``samples.parquet`` (indexed by instance)."""
    path = run_dir / SAMPLES_FILE
    if not path.is_file():
        raise BpsflowError(f"no samples in {run_dir}: run 'bpsflow sample CONFIG' first "
                           f"(expected {path})")
    return read_parquet(path).set_index("instance")
