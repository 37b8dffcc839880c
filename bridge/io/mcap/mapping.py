"""The file under a read-only memory map: opened (regular files only), CRC32 over a byte range,
and whole pages released from this process's resident memory once read."""

from __future__ import annotations

import mmap
import os
import stat
import zlib
from pathlib import Path
from typing import Any

from pendsim_mj.errors import RecordingError

from .records import MCAP_MAGIC, import_hint


def open_map(path: Path) -> tuple[Any, int]:
    """A read-only memory map of a regular file (FIFOs, devices and folders are refused)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot open: {exc.strerror}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise RecordingError(f"{path}: not a regular file (a FIFO, device or folder); pendsim reads .mcap files")
        size = info.st_size
        if size < len(MCAP_MAGIC):
            raise RecordingError(
                f"{path}: not an MCAP file ({size} bytes, shorter than the MCAP magic){import_hint(path)}"
            )
        return mmap.mmap(fd, 0, access=mmap.ACCESS_READ), size
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    finally:
        os.close(fd)


def crc32_range(buf: Any, start: int, stop: int) -> int:
    """CRC32 of buf[start:stop] in 16 MB pieces of a memoryview (no copy of the whole range),
    each piece's pages of the memory map released once read."""
    view = memoryview(buf)
    try:
        crc = 0
        for at in range(start, stop, 1 << 24):
            crc = zlib.crc32(view[at : min(at + (1 << 24), stop)], crc)
            release(buf, at, min(at + (1 << 24), stop))
        return crc
    finally:
        view.release()


def release(buf: Any, start: int, stop: int) -> None:
    """Drop the whole pages inside buf[start:stop] from this process's resident memory (a
    read-only file mapping: the kernel reads them again from its page cache if touched), so that
    walking a large file does not count it all as this process's memory. No-op for other buffers."""
    if not isinstance(buf, mmap.mmap) or not hasattr(mmap, "MADV_DONTNEED"):
        return
    first = -(-start // mmap.PAGESIZE) * mmap.PAGESIZE
    last = stop // mmap.PAGESIZE * mmap.PAGESIZE
    if last > first:
        buf.madvise(mmap.MADV_DONTNEED, first, last - first)
