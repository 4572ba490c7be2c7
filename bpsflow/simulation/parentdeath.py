"""Worker processes and engine runs die with the process that started them.

A ``bpsflow run`` killed with SIGKILL cannot clean up: without help its pool
workers, and the EnergyPlus processes they started, run on as orphans and
keep writing into the run directory for minutes, racing a resumed run. On
Linux the kernel can deliver a signal to a process when its parent dies
(``prctl(PR_SET_PDEATHSIG)``): workers ask for SIGKILL when bpsflow dies,
and each EnergyPlus process when its worker dies. Elsewhere these functions
do nothing (the orphans finish their current run, then exit).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable

_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>


def _prctl() -> Callable[..., int] | None:
    """libc's ``prctl``, looked up once (never between fork and exec)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl
    except (OSError, AttributeError):  # pragma: no cover - an unusual libc
        return None


_PRCTL = _prctl()


def die_with_parent(parent_pid: int | None = None) -> bool:
    """Ask the kernel to SIGKILL this process when its parent dies.

    Parameters
    ----------
    parent_pid : int, optional
        The process that should be the parent. If it died before the request
        took effect (this process was re-parented already), this process
        kills itself at once.

    Returns
    -------
    bool
        Whether the request is in place (False where the platform has no
        such mechanism).
    """
    if _PRCTL is None or _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
        return False
    if parent_pid is not None and os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGKILL)
    return True


def child_preexec() -> Callable[[], None] | None:
    """A ``preexec_fn`` for :mod:`subprocess` that makes the child die with this process.

    Returns None where the platform has no such mechanism (``subprocess``
    then starts the child as usual).
    """
    if _PRCTL is None:
        return None
    parent = os.getpid()
    prctl = _PRCTL
    kill, me, getppid, sigkill = os.kill, os.getpid, os.getppid, int(signal.SIGKILL)

    def preexec() -> None:
        # Between fork and exec: only the prepared calls, no imports, no allocation-heavy work.
        prctl(_PR_SET_PDEATHSIG, sigkill, 0, 0, 0)
        if getppid() != parent:
            kill(me(), sigkill)

    return preexec


_ARMED = False


def run_in_worker(parent_pid: int, function: Callable[..., object], *args: object) -> object:
    """Call ``function(*args)`` in a pool worker that dies with ``parent_pid``.

    The executor submits every task through this, so each worker process
    arms :func:`die_with_parent` once, before its first task writes anything.
    """
    global _ARMED
    if not _ARMED and os.getpid() != parent_pid:
        die_with_parent(parent_pid)
        _ARMED = True
    return function(*args)
