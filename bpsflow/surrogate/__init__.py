"""Bundled reduced-order (RC network) model of the shipped FLEXLAB-like test cell.

Runs every command without EnergyPlus (``backend: surrogate``, or ``auto``
when no EnergyPlus is found), sharing parameter names, tests and outputs
with the EnergyPlus model. See :mod:`bpsflow.surrogate.network` for the
model structure and :mod:`bpsflow.surrogate.outputs` for the EnergyPlus
output variables (zone, inside and outside faces, site) it reports.
"""

from bpsflow.surrogate.run import (ignored_targets, run_surrogate, simulate_instances,
                                   simulate_tidy)

__all__ = ["run_surrogate", "simulate_tidy", "simulate_instances", "ignored_targets"]
