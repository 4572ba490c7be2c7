"""The ``diagnosis:`` section of a config (pydantic only, no heavy imports).

``bpsflow diagnose`` (DESIGN.md §8) reads it; every key has a default, so a
config without the section diagnoses its first measured output::

    diagnosis:
      output: heating_power_w     # the measured output whose residuals are analysed
      holdout_days: 7             # the last days: never fitted, the gain is measured there
      alpha: 0.01                 # family-wise level of the driver tests (Holm)
      candidate_alpha: 0.05       # drivers below this still call candidates (cross-validated)
      min_share: 0.05             # a driver must explain this share of residual variance
      min_amplitude: 0.005        # ... and move the output by this fraction of its mean
      plausible_change: 0.5       # relative change of a fixed parameter still "plausible"
      extensions: [infiltration, internal_gain_schedule, scheduled_air_exchange,
                   solar_aperture, thermal_mass]
      zone: null                  # the zone the extensions are written for (see below)
      extension_zones: {}         # per extension, e.g. {solar_aperture: Office_East}
      max_rounds: 4               # extend, re-diagnose, at most this many times
      days_per_fold: 7            # cross-validation folds: blocks of whole days (a week)
      cv_candidates: 3            # causes cross-validated per round (the best by BIC)
      cv_iterations: 6            # refit steps per fold, from the calibration fit
      cv_refit: null              # simulated | linearised (default: simulated on the surrogate)
      shape_screen: true          # no driver significant: test every candidate's simulated shape
      start_screen: null          # Latin hypercube points screened for the base fit's starts
                                  # (null: 16 on EnergyPlus, 0 on the surrogate)
      fit_starts: 3               # ... the best of them fitted besides the nominal start
      parameter_margin_bic: 6.0   # an extension beats a refitted existing input by this BIC

``extensions: []`` switches the candidate extensions off: the diagnosis still
tests the residuals and checks the existing parameters, and says that no
extension was tried.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from bpsflow.schema import StrictModel

#: The extensions implemented on both backends (bpsflow/diagnosis/extensions.py). The
#: model's stratification is already an input (stratification_gradient,
#: return_air_offset), so a mis-valued one is a ``parameter`` verdict.
ExtensionName = Literal["infiltration_wind", "internal_gain_schedule", "solar_aperture",
                        "envelope_ua", "infiltration", "thermal_mass",
                        "scheduled_air_exchange"]

#: The default candidate families. ``infiltration`` fits the whole
#: ZoneInfiltration:DesignFlowRate law (A + B·|ΔT| + C·V + D·V², terms by BIC), so the
#: one-term ``infiltration_wind`` (C) and ``envelope_ua`` (A) are only tried when a
#: config lists them.
ALL_EXTENSIONS: list[ExtensionName] = ["infiltration", "internal_gain_schedule",
                                       "scheduled_air_exchange", "solar_aperture",
                                       "thermal_mass"]


class DiagnosisSettings(StrictModel):
    """Settings of ``bpsflow diagnose``.

    ``parameters`` are the existing parameters calibrated before the
    residuals are read (default: ``calibration.parameters`` when that names
    them, else the config's parameters with a continuous distribution; a
    sampler, discrete or empirical input stays at its nominal). Every *other*
    parameter is a candidate cause of a ``parameter`` verdict, within
    ``plausible_change`` (relative) of its nominal value, or within its
    distribution's 1–99 % range when it is uncertain.

    ``suspects`` limits the existing parameters whose signatures are
    computed (one simulation each; default: every unfitted parameter with a
    numeric value) — worth setting on EnergyPlus.

    ``parameter_candidates``: how many existing parameters, those whose
    characteristic signatures explain most of the residual, are refitted to
    see whether one of them removes the structure.

    ``gain_blocks``: how many on/off schedules of an internal gain are
    refitted (the shortlist of :func:`bpsflow.diagnosis.extensions.gain_blocks`).

    ``zone`` and ``extension_zones``: the zone (``Zone`` object name) every
    candidate extension's objects are written for, and per-extension
    exceptions to it. Without them the zone is the one the diagnosed output
    refers to (its ``key``: a zone name, e.g. for ``Zone Mean Air
    Temperature``; a zone equipment name, e.g. a
    ``ZoneHVAC:IdealLoadsAirSystem``, whose zone is found through
    ``ZoneHVAC:EquipmentList`` and ``ZoneHVAC:EquipmentConnections``; a zone
    air node, a space or a surface name), else the model's only zone; a
    multi-zone model whose output names no zone needs ``zone``
    (:func:`bpsflow.diagnosis.extensions.diagnosis_zone`).

    ``start_screen`` and ``fit_starts``: the fit of the existing parameters
    (the base model every verdict is measured against) starts from their
    nominal values and from the ``fit_starts`` best of ``start_screen``
    Latin-hypercube points over their ranges (one batch of runs, seeded by
    ``seed``); the lowest objective is kept. One local search can stop in a
    local minimum: a reheat after a night setback makes the objective rough
    on EnergyPlus. ``start_screen: 0`` fits from the nominal values only;
    the default (``null``) screens 16 points on EnergyPlus and none on the
    surrogate, whose objective is smooth: there a model-form error can pull
    the global minimum of the base fit far from the nominal values, and the
    extensions' joint fits, which start from the base fit, then stop short
    (a 40 m² hidden mass fitted as 25 m² instead of 37.5 m²).

    ``parameter_margin_bic``: when a plausible change of an existing input
    removes the structure, the candidate extensions are still fitted and
    cross-validated; the best one that passes replaces the ``parameter``
    verdict only if its BIC is lower by this margin (Kass & Raftery 1995:
    above 6, strong evidence), so a tie goes to the existing input.

    ``gain_alpha`` is the one-sided level of the out-of-fold
    forecast-encompassing test an extension must pass (besides a lower BIC and a lower held-out
    CV(RMSE)) to be accepted; after the last round every accepted extension
    must pass it again beside the others (backward pruning). A cause found by
    the shape screen (no driver significant) after another was accepted must
    pass at ``alpha`` instead: that residual holds the accepted cause's small
    misfit, and every candidate's shape was tried on it.

    ``cv_refit``: how each cross-validation fold is refitted: ``simulated``
    (a few Levenberg–Marquardt steps, one batch; the surrogate's default) or
    ``linearised`` (one bounded Gauss–Newton step on the calibration fit's
    Jacobian, at most 3 standard errors per parameter; EnergyPlus's default,
    as it costs no runs). Unset, a linearised refit that the data contradict
    (a candidate that fits better but predicts its folds worse, or a current
    model whose out-of-fold error is over 3 times its calibration error) is
    redone by simulation.
    """

    output: str | None = None
    holdout_days: int = Field(default=7, ge=1)
    parameters: list[str] | None = None
    alpha: float = Field(default=0.01, gt=0, lt=1)
    min_share: float = Field(default=0.05, ge=0, lt=1)
    min_amplitude: float = Field(default=0.005, ge=0)
    folds: int = Field(default=4, ge=2)
    plausible_change: float = Field(default=0.5, gt=0)
    gain_alpha: float = Field(default=0.05, gt=0, lt=1)
    candidate_alpha: float = Field(default=0.05, gt=0, lt=1)
    extensions: list[ExtensionName] = Field(default_factory=lambda: list(ALL_EXTENSIONS))
    zone: str | None = Field(default=None, min_length=1)
    extension_zones: dict[ExtensionName, str] = Field(default_factory=dict)
    max_rounds: int = Field(default=4, ge=1)
    days_per_fold: int = Field(default=7, ge=1)
    cv_candidates: int = Field(default=3, ge=1)
    cv_iterations: int = Field(default=6, ge=1)
    cv_refit: Literal["simulated", "linearised"] | None = None
    shape_screen: bool = True
    start_screen: int | None = Field(default=None, ge=0)
    fit_starts: int = Field(default=3, ge=0)
    parameter_margin_bic: float = Field(default=6.0, ge=0)
    gain_blocks: int = Field(default=4, ge=1)
    parameter_candidates: int = Field(default=3, ge=1)
    suspects: list[str] | None = None
    max_fit_iterations: int = Field(default=20, ge=1)
    ensemble_size: int = Field(default=50, ge=2)
    seed: int = 0

    @model_validator(mode="after")
    def _zones_of_listed_extensions(self) -> DiagnosisSettings:
        off = sorted(str(name) for name in self.extension_zones if name not in self.extensions)
        if off:
            # a zone for an extension that never runs would be ignored without a word
            raise ValueError(f"extension_zones: {', '.join(off)} is not in extensions "
                             f"({', '.join(map(str, self.extensions))}); expected zones for "
                             f"listed extensions only")
        return self

    @model_validator(mode="after")
    def _distinct(self) -> DiagnosisSettings:
        for key in ("extensions", "parameters", "suspects"):
            listed = getattr(self, key) or []
            repeated = sorted({str(v) for v in listed if listed.count(v) > 1})
            if repeated:
                # a candidate listed twice competes with itself for the cause
                raise ValueError(f"{key}: {', '.join(repeated)} listed more than once")
        return self
