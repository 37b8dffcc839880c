"""Recovering after damage: the next chunk in the file whose framing holds and whose CRC checks,
where the structural scan picks up the walk again so that every intact chunk after the damage
is kept."""

from __future__ import annotations

from typing import Any

from mcap.opcode import Opcode

from .chunks import inflate, read_chunk_ref
from .mapping import release
from .records import record_frame

WINDOW_BYTES = 1 << 24
"""The search goes through the file in windows of 16 MB, each window's pages released once
searched, so that a long stretch of damage (a file of zeros) does not become resident memory."""


def next_intact_chunk(buf: Any, size: int, start: int) -> int | None:
    """The offset of the next chunk at or after ``start`` in buf[:size] whose framing holds and
    whose CRC checks (each candidate is inflated); None if there is none."""
    at = start
    opcode = bytes([Opcode.CHUNK])
    while at < size:
        stop = min(size, at + WINDOW_BYTES)
        found = buf.find(opcode, at, stop)
        if found < 0:
            release(buf, at, stop)
            at = stop
            continue
        if _plausible_chunk(buf, size, found):
            return found
        release(buf, at, found)
        at = found + 1
    return None


def _plausible_chunk(buf: Any, size: int, at: int) -> bool:
    frame = record_frame(buf, size, at)
    if frame is None:
        return False
    try:
        ref = read_chunk_ref(buf, at, frame[1], frame[2])
    except ValueError:
        return False
    return not isinstance(inflate(buf, ref), Exception)
