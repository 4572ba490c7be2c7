"""Calibration of the simulation model to measured data (seed §2.3, §4.3; DESIGN.md §7).

Kennedy–O'Hagan Bayesian calibration ``y = η(x, θ) + δ(x) + ε`` (seed eq. 19)
with a GP emulator of η fitted by maximum likelihood (modular), θ, δ's
hyperparameters and σ_ε sampled with NUTS; the deterministic baseline
(bounded minimisation of a weighted NMBE² + CV(RMSE)²); held-out testing of
the emulator, the GP prediction and the physical model re-run on posterior
draws; and data scenarios (seed Table 4.1).

Modules: :mod:`~bpsflow.calibration.settings` (the config section),
:mod:`~bpsflow.calibration.design` (calibration parameters, LHD, runs, the
observation and simulation tables with variable inputs x),
:mod:`~bpsflow.calibration.emulator` (the GP emulator),
:mod:`~bpsflow.calibration.bayes` (the KOH model in NumPyro, NUTS, diagnostics),
:mod:`~bpsflow.calibration.deterministic` (the baseline),
:mod:`~bpsflow.calibration.heldout` (held-out metrics),
:mod:`~bpsflow.calibration.report` (files and figures),
:mod:`~bpsflow.calibration.scenarios` (the workflow, one scenario or all).

Importing this package is cheap: JAX is loaded only by the modules that need it.
"""
