"""The process's heap (glibc's allocator; elsewhere every call here does nothing).

``pendsim`` keeps blocks under 32 MB in the heap (``keep_small_blocks``: chunk-by-chunk work
would otherwise fault in fresh pages again and again); the long-run arrays freed between stages
(a 6 h recording's decoded samples, one model run's series) then stay resident, in pieces the
next stage cannot always reuse. ``trim`` returns every free page of the heap to the system, and
``map_large_blocks`` gives a command's large arrays pages of their own. Python's own garbage
collector (``collect_rarely``, ``skip_exit_collection``) is tuned here too.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc

KEEP_BYTES = 32 << 20
"""Freed blocks below this stay in the process's heap instead of going back to the system."""
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # malloc.h


def _mallopt(param: int, value: int) -> None:
    with contextlib.suppress(OSError, AttributeError, TypeError):
        ctypes.CDLL(None).mallopt(param, int(value))  # the process's own symbols: glibc's where it is glibc


def keep_small_blocks() -> None:
    """Allocate blocks under ``KEEP_BYTES`` from the heap and keep up to twice that free at its
    top. Work done chunk by chunk (reading a recording, simulating in blocks) frees and allocates
    the same few MB again and again; with glibc's defaults each time comes back as fresh pages
    (measured: reading a 6 h recording, 0.9 million page faults and 1.5 s of system time, against
    17 thousand and 0.5 s)."""
    _mallopt(M_MMAP_THRESHOLD, KEEP_BYTES)
    _mallopt(M_TRIM_THRESHOLD, 2 * KEEP_BYTES)


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
    keeps up to 32 MB there: ``keep_small_blocks``). For work whose large arrays come and go
    (validate: each comparison's whole-run temporaries), resident memory then follows what is
    alive instead of the heap's high-water mark; blocks smaller than that (chunks, model blocks)
    stay in the heap. Elsewhere (or if the call fails): nothing."""
    _mallopt(M_MMAP_THRESHOLD, min_bytes)


YOUNG_OBJECTS = 50_000
"""Python's cyclic garbage collector looks at the youngest objects after this many allocations
(Python's default: 700). Importing scipy, matplotlib and numba makes hundreds of thousands of
objects that live as long as the process; with the default, an Allan analysis ran 553
collections (4 over everything), 0.26 s of a 5 s run."""


def collect_rarely() -> None:
    """Run the cyclic garbage collector less often (``YOUNG_OBJECTS``; a full collection after
    20 of the middle generation's). Cycles are still collected; arrays are freed by reference
    counting as ever."""
    gc.set_threshold(YOUNG_OBJECTS, 20, 20)


def skip_exit_collection() -> None:
    """Before the process exits: move every object to the collector's permanent generation, so
    that Python's exit does not walk all of them once more (0.3-0.5 s after an Allan analysis
    with its libraries loaded). Only for a process whose outputs are all written and closed:
    an object left in a reference cycle is then not finalized."""
    gc.freeze()
