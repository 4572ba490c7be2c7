"""``bpsflow diagnose``: what the simulation gets wrong, its cause, a fix, the gain (DESIGN.md §8).

Modules, one concept each:

* :mod:`~bpsflow.diagnosis.settings` — the config's ``diagnosis:`` section;
* :mod:`~bpsflow.diagnosis.drivers` — candidate drivers from the weather file,
  the time axis and extra measured columns;
* :mod:`~bpsflow.diagnosis.structure` — tests of residual structure per driver
  (HAC errors, multiple testing, effect size, blocked folds, whiteness);
* :mod:`~bpsflow.diagnosis.comparison` — out-of-fold encompassing and loss-difference tests, BIC;
* :mod:`~bpsflow.diagnosis.fitting` — fitting parameters on either backend, scores;
* :mod:`~bpsflow.diagnosis.signatures` — characteristic signatures of parameters;
* :mod:`~bpsflow.diagnosis.extensions` — candidate model extensions (IDF objects);
* :mod:`~bpsflow.diagnosis.workflow` — the four steps;
* :mod:`~bpsflow.diagnosis.report` — ``diagnosis.json``, ``diagnosis.md`` and figures.

This package's ``__init__`` stays import-light: :mod:`bpsflow.config` imports
the settings module.
"""
