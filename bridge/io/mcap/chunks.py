"""Chunk inflation: where a chunk lies (``ChunkRef``, read from its record's head) and its records
inflated with a size and ratio cap and checked against its CRC, the next few ahead on one pool
thread while the caller parses (``inflate_ahead``)."""

from __future__ import annotations

import dataclasses
import itertools
import zlib
from collections import deque
from collections.abc import Generator, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from .records import (
    CHUNK_HEAD,
    INDEX_ENTRY,
    RECORD_HEAD,
    DecompressionError,
    check_inflation,
    decompress,
)

CHUNK_COMPRESSIONS = ("", "zstd", "lz4")  # the Chunk.compression strings pendsim reads
INFLATE_AHEAD = 2
"""Chunks inflated ahead of the one being parsed (``McapFile.chunks``): more was measured no faster."""


@dataclasses.dataclass(frozen=True)
class ChunkRef:
    """Where one chunk lies and what its index says (nothing inflated).

    Attributes:
      offset, length: the Chunk record's first byte and total length, bytes.
      start_ns, end_ns: its message time range.
      compression: "", "zstd" or "lz4".
      data_start, data_size: the compressed records' place in the file, bytes.
      uncompressed_size, uncompressed_crc: as the chunk declares them.
      index: channel id -> (offset, length) of its MessageIndex record after the chunk.
    """

    offset: int
    length: int
    start_ns: int
    end_ns: int
    compression: str
    data_start: int
    data_size: int
    uncompressed_size: int
    uncompressed_crc: int
    index: dict[int, tuple[int, int]]

    def index_count(self, channel: int) -> int:
        """Messages the index lists for ``channel``."""
        at = self.index.get(channel)
        return 0 if at is None else (at[1] - RECORD_HEAD.size - 6) // INDEX_ENTRY.itemsize


def read_chunk_ref(buf: Any, at: int, body: int, end: int) -> ChunkRef:
    """The ChunkRef of the Chunk record at ``at`` (body from ``body`` to ``end``), its message
    index still empty.

    Raises:
      ValueError: a field is damaged, the compression is not one pendsim reads, or the declared
        size breaks the inflation limits.
    """
    if body + CHUNK_HEAD.size + 4 > end:
        raise ValueError("chunk too short for its fields")
    start_ns, end_ns, usize, ucrc = CHUNK_HEAD.unpack_from(buf, body)
    p = body + CHUNK_HEAD.size
    (clen,) = np.frombuffer(buf, "<u4", 1, p)
    if clen > 16 or p + 4 + clen + 8 > end:
        raise ValueError("chunk's compression field is damaged")
    try:
        compression = bytes(buf[p + 4 : p + 4 + clen]).decode()
    except UnicodeDecodeError:
        raise ValueError("chunk's compression field is damaged") from None
    if compression not in CHUNK_COMPRESSIONS:
        raise ValueError(f"chunk compression {compression!r} is not one pendsim reads (zstd, lz4, none)")
    p += 4 + clen
    (dlen,) = np.frombuffer(buf, "<u8", 1, p)
    if p + 8 + int(dlen) != end:
        raise ValueError(f"chunk's records ({int(dlen)} bytes) do not fill its record ({end - p - 8} bytes)")
    if end_ns < start_ns:
        raise ValueError("chunk ends before it starts (message_end_time < message_start_time)")
    try:
        check_inflation(compression, int(dlen), usize)
    except DecompressionError as exc:
        raise ValueError(str(exc)) from None
    return ChunkRef(at, end - at, start_ns, end_ns, compression, p + 8, int(dlen), usize, ucrc, {})


def total_range(chunks: list[ChunkRef]) -> tuple[int, int]:
    """The (first, last) message log time of these chunks, ns."""
    return min(r.start_ns for r in chunks), max(r.end_ns for r in chunks)


def inflate(buf: Any, ref: ChunkRef) -> bytes | Exception:
    """Inflate and CRC-check one chunk (zstd, lz4 and zlib release the GIL)."""
    try:
        raw = decompress(ref.compression, buf[ref.data_start : ref.data_start + ref.data_size], ref.uncompressed_size)
        if ref.uncompressed_crc and zlib.crc32(raw) != ref.uncompressed_crc:
            raise DecompressionError("CRC mismatch: the chunk's records are damaged")
        return raw
    except DecompressionError as exc:
        return exc


def inflate_ahead(buf: Any, refs: Iterable[ChunkRef]) -> Generator[tuple[ChunkRef, bytes | Exception], None, None]:
    """Each chunk of ``refs`` in order with ``inflate``'s answer (its records, or what is wrong),
    the next ``INFLATE_AHEAD`` inflated meanwhile on one pool thread while the caller parses.

    The thread ends when the walk does; a caller that stops early closes the generator
    (``contextlib.closing``), which cancels the inflations still queued and waits for the one
    running, so that none is left running on the memory map.
    """
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="mcap-inflate") as pool:
        pending: deque[tuple[ChunkRef, Future[bytes | Exception]]] = deque()
        upcoming = iter(refs)
        try:
            for ref in itertools.islice(upcoming, INFLATE_AHEAD):
                pending.append((ref, pool.submit(inflate, buf, ref)))
            while pending:
                ref, inflating = pending.popleft()
                following = next(upcoming, None)
                if following is not None:
                    pending.append((following, pool.submit(inflate, buf, following)))
                yield ref, inflating.result()
        finally:  # a consumer that stops early: no inflation left running on the map
            for _, inflating in pending:
                inflating.cancel()
