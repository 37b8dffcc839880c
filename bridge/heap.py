"""The process's heap: freed memory handed back to the system between the stages of long work.

``pendsim`` keeps blocks under 32 MB in glibc's heap (``cli._tune_malloc``: chunk-by-chunk work
would otherwise fault in fresh pages again and again); the long-run arrays freed between stages
(a 6 h recording's decoded samples, one model run's series) then stay resident, in pieces the
next stage cannot always reuse. ``trim`` returns every free page of the heap to the system.
"""

from __future__ import annotations

import contextlib
import ctypes


def trim() -> None:
    """Hand the heap's free pages back to the system (glibc's ``malloc_trim(0)``: whole free
    pages anywhere in the heap, not only at its top). Elsewhere (no glibc): nothing."""
    with contextlib.suppress(OSError, AttributeError, TypeError):
        ctypes.CDLL(None).malloc_trim(0)
