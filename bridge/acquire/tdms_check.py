"""TDMS files checked by their structure before npTDMS reads them.

A TDMS file is a chain of segments, each opened by a 28-byte lead-in: the tag ``TDSm``, the table
of contents (a little-endian bit mask; ``kTocBigEndian`` says the rest of the segment is
big-endian), then in the segment's byte order the version (4712: TDMS 1.0, 4713: 2.0), the
offset of the next segment and that of the raw data (NI, "TDMS File Format Internal
Structure"). npTDMS reads a cut or unfinished file as far as it can, with a warning, and crops
data that do not fill its channels: ``check_tdms_segments`` walks the chain first, and
``NptdmsWarnings`` collects what npTDMS warns about, each a reason to refuse the file.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import BinaryIO, Literal

from pendsim_mj.errors import RecordingError

TDMS_VERSIONS = (4712, 4713)  # the lead-in's version number: TDMS 1.0 and 2.0
TDMS_BIG_ENDIAN = 1 << 6  # kTocBigEndian in a lead-in's table of contents (always little-endian itself)
TDMS_UNFINISHED = 2**64 - 1  # the next-segment offset a writer leaves while the segment is being written


def check_tdms_segments(path: Path) -> int:
    """Walk a TDMS file's segments by their lead-ins (28 bytes each: "TDSm", the table of contents,
    then in the segment's byte order the version, the next segment's offset and the raw data's
    offset; big-endian where the contents say so) and return how many there are.

    Raises:
      RecordingError: not a TDMS file, or a segment cut short, never finished or damaged.
    """
    try:
        with open(path, "rb") as f:
            return _walk_tdms_segments(path, f, path.stat().st_size)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None


def _walk_tdms_segments(path: Path, f: BinaryIO, size: int) -> int:
    """``check_tdms_segments`` on the open file ``f`` of ``size`` bytes."""
    position, count = 0, 0
    while position < size:
        f.seek(position)
        lead = f.read(28)
        where = f"segment {count + 1} at byte {position}"
        before = f" ({count} complete segment{'s' if count > 1 else ''} before it)" if count else ""
        if lead[:4] != b"TDSm":
            if count == 0:
                raise RecordingError(f"{path}: not a TDMS file (it does not start with a TDMS lead-in, 'TDSm')")
            raise RecordingError(f"{path}: damaged TDMS file: {where} has no 'TDSm' lead-in{before}")
        toc = int.from_bytes(lead[4:8], "little")
        order: Literal["big", "little"] = "big" if toc & TDMS_BIG_ENDIAN else "little"
        version = int.from_bytes(lead[8:12], order)
        if len(lead) >= 12 and version not in TDMS_VERSIONS:
            what = "not a TDMS file" if count == 0 else "damaged TDMS file"
            raise RecordingError(
                f"{path}: {what}: {where} has version {version} (TDMS 1.0 is 4712, 2.0 is 4713, {order}-endian here)"
            )
        if len(lead) < 28:
            raise RecordingError(
                f"{path}: truncated TDMS file: {where} ends after {len(lead)} of its lead-in's 28 bytes{before}"
            )
        following, raw = int.from_bytes(lead[12:20], order), int.from_bytes(lead[20:28], order)
        if following == TDMS_UNFINISHED:
            raise RecordingError(
                f"{path}: unfinished TDMS file: {where} was never closed (its length is unset: the writer stopped "
                f"while writing it){before}"
            )
        if raw > following:
            raise RecordingError(
                f"{path}: damaged TDMS file: {where} puts its data {raw} bytes in, past its own end ({following})"
            )
        if position + 28 + following > size:
            raise RecordingError(
                f"{path}: truncated TDMS file: {where} claims {following} bytes after its lead-in; the file ends "
                f"{position + 28 + following - size} bytes short{before}"
            )
        position += 28 + following
        count += 1
    if count == 0:
        raise RecordingError(f"{path}: an empty file, not a TDMS file")
    return count


class NptdmsWarnings(logging.Handler):
    """npTDMS's warnings while it reads (a damaged segment, data cropped): each one a reason to refuse."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())
