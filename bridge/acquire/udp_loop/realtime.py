"""Real-time scheduling for the loops over UDP, where the OS permits it.

A 100 Hz loop on a shared machine misses its deadlines whenever the scheduler runs something
else first: with two busy neighbours on two cores, a normal-priority Python loop woke 10-100 ms
late (measured). Linux's SCHED_FIFO runs a ready real-time thread before every normal one, so the
loop (which sleeps between its events and never spins) wakes on time; the kernel's real-time
throttling (95 % of each second by default) keeps a runaway thread from starving the machine.
It needs root or CAP_SYS_NICE: elsewhere the loop runs at normal priority and says so.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

PRIORITY = 10  # SCHED_FIFO 1-99: low, above every normal thread, below the kernel's own


@contextlib.contextmanager
def realtime(enabled: bool = True, priority: int = PRIORITY) -> Iterator[bool]:
    """Within the block the calling thread runs under SCHED_FIFO at ``priority`` (children it
    starts do not inherit it), its previous policy back after, however the block ends; yields
    whether real-time scheduling was granted (False: not asked, not Linux, or not permitted)."""
    setter = getattr(os, "sched_setscheduler", None)
    if not enabled or setter is None:
        yield False
        return
    previous = (os.sched_getscheduler(0), os.sched_getparam(0))
    try:
        setter(0, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(priority))
    except OSError:  # PermissionError: neither root nor CAP_SYS_NICE
        yield False
        return
    try:
        yield True
    finally:
        setter(0, previous[0], previous[1])


__all__ = ["PRIORITY", "realtime"]
