"""Set-up of each worker process of a Dask ``LocalCluster`` that bpsflow starts (a worker preload).

Ctrl-C in a terminal reaches the whole foreground process group: the command
and every worker. The command handles it (it cancels what has not run, keeps
the run directory resumable and closes the cluster, which ends the workers
and, through ``PR_SET_PDEATHSIG``, their EnergyPlus runs); a worker that took
it too would only print its own traceback.
"""

from __future__ import annotations

from typing import Any

from bpsflow.simulation.executor import leave_interrupt_to_parent


def dask_setup(worker: Any) -> None:
    """Called by Dask in each new worker process (also one a nanny restarts)."""
    leave_interrupt_to_parent()
