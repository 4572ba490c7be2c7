"""Set-up of each worker process of a Dask ``LocalCluster`` that bpsflow starts (a worker preload).

Ctrl-C in a terminal reaches the whole foreground process group: the command
and every worker. The command handles it (it cancels what has not run, keeps
the run directory resumable and closes the cluster, which ends the workers
and, through ``PR_SET_PDEATHSIG``, their EnergyPlus runs); a worker that took
it too would only print its own traceback.

When the command closes the cluster, a worker's heartbeat can be in flight as
the scheduler goes away; Dask then logs the lost connection with its
traceback. The command itself reports why it stopped, so that record is
dropped (a scheduler lost while the command runs surfaces in the command).
"""

from __future__ import annotations

import logging
from typing import Any

from bpsflow.simulation.executor import leave_interrupt_to_parent

#: Messages of ``distributed.worker`` that only say the scheduler has gone.
SCHEDULER_GONE_MESSAGES = ("Failed to communicate with scheduler during heartbeat",)


class SchedulerGoneFilter(logging.Filter):
    """Drops a worker's record of a lost scheduler connection (see the module's note)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = str(record.msg)
        return not any(message.startswith(gone) for gone in SCHEDULER_GONE_MESSAGES)


def dask_setup(worker: Any) -> None:
    """Called by Dask in each new worker process (also one a nanny restarts)."""
    leave_interrupt_to_parent()
    worker_logger = logging.getLogger("distributed.worker")
    if not any(isinstance(existing, SchedulerGoneFilter) for existing in worker_logger.filters):
        worker_logger.addFilter(SchedulerGoneFilter())
