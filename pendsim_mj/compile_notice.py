"""One line when numba compiles pendsim's kernels (a cold cache: the first run after installing,
or a new ``NUMBA_CACHE_DIR``), so that a first command that is silent for 20 s to 2 minutes says
why. pendsim_mj prints nothing itself: the command line sets the notice (``set_notice``), a
script may too. Loaded cache entries say nothing.

Each module that defines kernels calls ``watch()`` after importing numba; it registers one
listener for numba's "numba:compile" event, which numba triggers only when a function is
compiled, never when it is loaded from its cache.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

COLD_COMPILE_S = "about 20 s; longer on a busy machine"
"""What a cold compile of the planar kernels costs (measured on 2 cores: 17-20 s CPU)."""

_notice: Callable[[str], None] | None = None
_said = False
_watching = False


def set_notice(notice: Callable[[str], None] | None) -> None:
    """Call ``notice`` with one line, once per process, when numba first compiles a kernel."""
    global _notice
    _notice = notice


def _cache_folder(dispatcher: Any) -> str:
    """Where numba keeps the compiled function (beside the source, or NUMBA_CACHE_DIR)."""
    cache = getattr(dispatcher, "_cache", None)
    path = getattr(cache, "_cache_path", None)
    return str(path) if path else os.environ.get("NUMBA_CACHE_DIR", "numba's cache folder")


def message(dispatcher: Any) -> str:
    """The line said on a cold compile, naming where the result is kept."""
    return f"compiling pendsim's numba kernels once ({COLD_COMPILE_S}; cached in {_cache_folder(dispatcher)})"


def watch() -> None:
    """Listen for numba compiling (once per process; numba must be importable)."""
    global _watching
    if _watching:
        return
    from numba.core import event  # start-up: called by modules that have just imported numba

    class _Listener(event.Listener):
        def on_start(self, ev: Any) -> None:
            global _said
            if _said or _notice is None:
                return
            _said = True
            _notice(message(ev.data.get("dispatcher") if isinstance(ev.data, dict) else None))

        def on_end(self, ev: Any) -> None:
            pass

    event.register("numba:compile", _Listener())
    _watching = True
