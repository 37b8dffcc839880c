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


MAPPED_BYTES = 4 << 20
"""Blocks of at least this many bytes get pages of their own (``map_large_blocks``): a long run's
whole-run arrays (0.5 million float64 values and up), never the blocks the work goes in."""


def map_large_blocks(min_bytes: int = MAPPED_BYTES) -> None:
    """glibc only: allocate blocks of ``min_bytes`` and more as pages of their own (mmap), which
    go back to the system the moment they are freed, instead of from the heap (``pendsim``
    keeps up to 32 MB there: ``cli._tune_malloc``). For work whose large arrays come and go
    (validate: each comparison's whole-run temporaries), resident memory then follows what is
    alive instead of the heap's high-water mark; blocks smaller than that (chunks, model blocks)
    stay in the heap. Elsewhere (or if the call fails): nothing."""
    with contextlib.suppress(OSError, AttributeError, TypeError):
        m_mmap_threshold = -3  # malloc.h
        ctypes.CDLL(None).mallopt(m_mmap_threshold, int(min_bytes))
