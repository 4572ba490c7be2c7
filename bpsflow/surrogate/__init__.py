"""Bundled reduced-order (RC network) model of a single-zone test cell.

Runs every command without EnergyPlus (``backend: surrogate``, or ``auto``
when no EnergyPlus is found) for a model it can represent (see
:mod:`bpsflow.surrogate.support`), sharing parameter names, tests and outputs
with the EnergyPlus model. See :mod:`bpsflow.surrogate.network` for the
model structure and :mod:`bpsflow.surrogate.outputs` for the EnergyPlus
output variables (zone, inside and outside faces, site) it reports. It runs
through the simulation layer (:mod:`bpsflow.simulation.surrogate`).
"""
