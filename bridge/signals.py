"""Interrupts held back while code that would swallow them runs.

numba compiles or loads its compiled code through llvmlite, which calls back into Python through
ctypes: a KeyboardInterrupt raised inside such a callback (Ctrl-C at that moment) is printed as
"Exception ignored on calling ctypes callback function" and lost, and the command then runs to its
end (seen about once in 60 interrupts of ``pendsim allan`` at 0.5 s). An interrupt while a
module initialises (a C extension's init, e.g. glfw's) can leave an ImportError instead of a
clean stop. ``interrupts_deferred`` holds SIGINT and SIGTERM back for such a block and delivers
the first one, to whatever handler was there before, as soon as it ends.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator, Mapping
from typing import Any

DEFERRED = (signal.SIGINT, signal.SIGTERM)


Handler = Callable[[int, Any], Any] | int | signal.Handlers | None


@contextlib.contextmanager
def signal_handlers(handlers: Mapping[int, Handler]) -> Iterator[bool]:
    """Within the block, each signal is handled by its handler (a function, ``signal.SIG_DFL`` or
    ``signal.SIG_IGN``); after it, every handler from before is back, however the block ends, even
    when a signal's handler raises while they are being installed or restored (the restoring goes
    on, then the exception). Left behind, an ignored SIGINT would be inherited by every process
    started later, which then cannot be stopped with Ctrl-C. Main thread only (where Python lets
    handlers be set); elsewhere nothing changes and the block gets False."""
    if threading.current_thread() is not threading.main_thread():
        yield False
        return
    previous: list[tuple[int, Handler]] = []
    try:
        for signum, handler in handlers.items():
            previous.append((signum, signal.getsignal(signum)))
            signal.signal(signum, handler)
        yield True
    finally:
        _restore(previous)


def _restore(previous: list[tuple[int, Handler]]) -> None:
    if not previous:
        return
    (signum, handler), rest = previous[0], previous[1:]
    try:
        signal.signal(signum, handler)
    finally:
        _restore(rest)


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM are noted instead of handled; the first one noted is
    raised again (``signal.raise_signal``) when the block ends, normally or not, so that the
    handlers installed before (Python's KeyboardInterrupt, a command's own) act on it then.
    Outside the main thread (where signal handlers cannot be set): no effect."""
    noted: list[int] = []

    def note(signum: int, frame: object) -> None:
        noted.append(signum)

    try:
        with signal_handlers(dict.fromkeys(DEFERRED, note)):
            yield
    finally:
        if noted:
            signal.raise_signal(noted[0])
