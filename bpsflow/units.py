"""Output units: the unit a config declares against the unit EnergyPlus reports.

An output's ``unit`` is more than a label: it decides whether measured values
are summed or averaged over an interval (:mod:`bpsflow.measured`) and what a
decision outcome may compute (:mod:`bpsflow.decision.intervention`). A
``J`` meter declared ``kWh`` without the factor would label joules as
kilowatt-hours, so the reported unit is compared with the declared one and
the declared ``scale`` with the factor between them.
"""

from __future__ import annotations

import math

#: Spellings of one unit, in upper case, mapped to EnergyPlus's.
_SYNONYMS = {"°C": "C", "DEGC": "C", "DEG C": "C", "CELSIUS": "C", "W/M²": "W/M2",
             "KWH": "KWH", "WATT": "W", "WATTS": "W", "JOULE": "J", "JOULES": "J"}

#: Factors from a unit EnergyPlus reports to a unit users often declare (value × factor).
CONVERSIONS: dict[tuple[str, str], float] = {
    ("J", "KJ"): 1e-3, ("J", "MJ"): 1e-6, ("J", "GJ"): 1e-9,
    ("J", "WH"): 1 / 3600, ("J", "KWH"): 1 / 3.6e6, ("J", "MWH"): 1 / 3.6e9,
    ("W", "KW"): 1e-3, ("W", "MW"): 1e-6, ("W/M2", "KW/M2"): 1e-3,
}


def normalise_unit(unit: str) -> str:
    """``unit`` in one spelling: upper case, no spaces, ``°C``/``degC`` as ``C``."""
    text = " ".join(unit.strip().upper().split())
    return _SYNONYMS.get(text, text.replace(" ", ""))


def unit_mismatch(declared: str, scale: float, reported: str) -> str | None:
    """Why ``declared`` (with ``scale``) cannot be ``reported`` values, or None when it can.

    Parameters
    ----------
    declared : str
        The config's ``outputs.<name>.unit`` (empty: not declared, nothing to check).
    scale : float
        The config's ``outputs.<name>.scale`` (reported value × scale = declared value).
    reported : str
        The unit EnergyPlus reports the variable or meter in (empty: none to compare).

    Returns
    -------
    str or None
        A sentence saying what is inconsistent and what to write instead.
        The same unit with any scale (a multiplier or a sign) passes, and so
        do unknown unit pairs with a scale other than 1 (the user's own
        conversion, e.g. J to kWh/m²).
    """
    if not declared.strip() or not reported.strip():
        return None
    have, want = normalise_unit(reported), normalise_unit(declared)
    factor = CONVERSIONS.get((have, want))
    if have == want:
        return None   # a scale here is a multiplier or a sign, not a conversion
    if factor is not None:
        if math.isclose(abs(scale), factor, rel_tol=1e-3):
            return None
        return (f"EnergyPlus reports it in {reported}; unit {declared} needs scale {factor:.6g} "
                f"({reported} to {declared}), got scale {scale:g}")
    if scale == 1:
        return (f"EnergyPlus reports it in {reported}, not {declared}: expected unit "
                f"{reported}, or unit {declared} with the scale that converts {reported} to it")
    return None
