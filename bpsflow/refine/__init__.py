"""Uncertainty propagation using detailed measurements (seed §3.4.3–3.5; ``bpsflow refine``).

Modules:

- :mod:`~bpsflow.refine.inputs` — reading and checking ``detailed.csv``,
  ``sensor_calibration.csv`` and ``detailed.json``;
- :mod:`~bpsflow.refine.estimators` — the estimators of eq. 8–18 and the
  solar ratios, one function each;
- :mod:`~bpsflow.refine.parameters` — matching estimates to config parameters
  by target, units, refined distributions and intervals;
- :mod:`~bpsflow.refine.refinement` — :func:`refine`, the whole step;
- :mod:`~bpsflow.refine.report` — ``refined.yaml``, ``refine.json``, CSV, figures.
"""

from bpsflow.refine.refinement import RefinedParameter, Refinement, refine
from bpsflow.refine.report import interval_table, write_refinement

__all__ = ["Refinement", "RefinedParameter", "refine", "interval_table", "write_refinement"]
