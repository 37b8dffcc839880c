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
from collections.abc import Iterator

DEFERRED = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM are noted instead of handled; the first one noted is
    raised again (``signal.raise_signal``) when the block ends, normally or not, so that the
    handlers installed before (Python's KeyboardInterrupt, a command's own) act on it then.
    Outside the main thread (where signal handlers cannot be set): no effect."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []

    def note(signum: int, frame: object) -> None:
        noted.append(signum)

    previous = {s: signal.signal(s, note) for s in DEFERRED}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if noted:
            signal.raise_signal(noted[0])
