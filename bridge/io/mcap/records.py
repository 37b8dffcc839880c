"""The byte layouts of the MCAP records pendsim builds and parses in bulk, defined once for the
writer and the reader (https://mcap.dev/spec), and bounded decompression.

Every record is ``opcode (u8) | length (u64 LE) | body`` (``record_frame`` finds one in a
buffer). The layouts here are the ones handled with numpy or ``struct`` instead of
``mcap.records`` (messages, message indexes, chunk heads, the footer); the others (schema,
channel, metadata, attachment, indexes, statistics) are framed and parsed with ``mcap.records``
(``parse_record``).
"""

from __future__ import annotations

import io
import struct
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode

MCAP_MAGIC = b"\x89MCAP0\r\n"

LAB_FILE_SUFFIXES = (".csv", ".lvm", ".tdms")  # what ``pendsim import`` turns into a recording


def import_hint(path: Path) -> str:
    """For a lab file (CSV, LabVIEW .lvm, TDMS by its extension) given where a recording is read:
    the command that converts it, to end a "not an MCAP file" message; else ""."""
    if path.suffix.lower() not in LAB_FILE_SUFFIXES:
        return ""
    kind = path.suffix.lower()[1:].upper()
    return f"; a {kind} lab file becomes a recording with 'pendsim import {path} -o run.mcap'"


RECORD_HEAD = struct.Struct("<BQ")  # opcode, body length
# A Message record: opcode, length, channel id, sequence, log time, publish time, then the data.
MESSAGE_PREFIX = np.dtype(
    [
        ("opcode", "u1"),
        ("length", "<u8"),
        ("channel", "<u2"),
        ("sequence", "<u4"),
        ("log_time", "<u8"),
        ("publish_time", "<u8"),
    ]
)
MESSAGE_PREFIX_SIZE = MESSAGE_PREFIX.itemsize  # 31 bytes: 9 of framing, 22 of fields
MESSAGE_FIELDS = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time (22 bytes)
# A MessageIndex record's entries: (log time, offset of the message in the uncompressed chunk).
INDEX_ENTRY = np.dtype([("timestamp", "<u8"), ("offset", "<u8")])
MESSAGE_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, length, channel id, entries' byte length
# A Chunk body: start, end, uncompressed size, uncompressed CRC; then the compression string
# (u32 length + text) and the records (u64 length + bytes).
CHUNK_HEAD = struct.Struct("<QQQI")
FOOTER_BODY = struct.Struct("<QQI")  # summary start, summary offset start, summary CRC
FOOTER_SIZE = RECORD_HEAD.size + FOOTER_BODY.size  # 29 bytes
DATA_END_SIZE = RECORD_HEAD.size + 4
COMPRESSIONS = ("zstd", "lz4", "none")
FILE_COMPRESSION = {"zstd": "zstd", "lz4": "lz4", "none": ""}  # option -> Chunk.compression

SUMMARY_OPCODES = frozenset(
    {
        Opcode.SCHEMA,
        Opcode.CHANNEL,
        Opcode.CHUNK_INDEX,
        Opcode.ATTACHMENT_INDEX,
        Opcode.METADATA_INDEX,
        Opcode.STATISTICS,
        Opcode.SUMMARY_OFFSET,
    }
)


def record_frame(buf: Any, size: int, at: int) -> tuple[int, int, int] | None:
    """(opcode, body start, end) of the record at ``at`` in buf[:size], or None if it cannot fit."""
    if at + RECORD_HEAD.size > size:
        return None
    opcode, length = RECORD_HEAD.unpack_from(buf, at)
    end = at + RECORD_HEAD.size + length
    if end > size:
        return None
    return opcode, at + RECORD_HEAD.size, end


def parse_record(cls: Any, body: bytes | memoryview) -> Any:
    """One record (an ``mcap.records`` class) from its body, which it must fill exactly.

    Raises:
      ValueError: the body is damaged, naming the record type.
    """
    stream = ReadDataStream(io.BytesIO(bytes(body)))
    try:
        record = cls.read(stream)
    except Exception as exc:  # EndOfFile, struct.error, UnicodeDecodeError: damaged
        raise ValueError(f"damaged {cls.__name__} record ({type(exc).__name__})") from None
    if stream.count != len(body):
        raise ValueError(f"damaged {cls.__name__} record (its fields fill {stream.count} of {len(body)} bytes)")
    return record


# Decompression limits: a chunk may not claim more than MAX_CHUNK_BYTES uncompressed, nor more
# than MAX_RATIO times its compressed size once past RATIO_FREE_BYTES (zstd on IMU data reaches
# 3-10x; a chunk of constant values about 100x; 1000x is a bomb). Output is read with a bound,
# so a stream that lies about its size costs at most the claimed size + 1 byte.
MAX_CHUNK_BYTES = 256 * 1024 * 1024
MAX_RATIO = 1000
RATIO_FREE_BYTES = 1024 * 1024


class DecompressionError(ValueError):
    """A chunk that cannot be decompressed to its declared size within the limits."""


def check_inflation(compression: str, compressed_size: int, uncompressed_size: int) -> None:
    """Refuse a chunk whose declared uncompressed size breaks the limits, before inflating it."""
    if uncompressed_size > MAX_CHUNK_BYTES:
        raise DecompressionError(f"chunk claims {uncompressed_size} bytes uncompressed (limit {MAX_CHUNK_BYTES})")
    if compression and uncompressed_size > max(RATIO_FREE_BYTES, MAX_RATIO * compressed_size):
        raise DecompressionError(
            f"chunk claims {uncompressed_size} bytes from {compressed_size} compressed "
            f"(more than {MAX_RATIO}x: refused as a decompression bomb)"
        )


def decompress(compression: str, data: bytes | memoryview, uncompressed_size: int) -> bytes:
    """Inflate one chunk's records to exactly ``uncompressed_size`` bytes, reading at most one
    byte more (bounded memory whatever the stream holds).

    Raises:
      DecompressionError: unknown compression, limits exceeded, a damaged stream, or a size
        other than the declared one.
    """
    check_inflation(compression, len(data), uncompressed_size)
    try:
        if compression == "":
            raw = bytes(data)
        elif compression == "zstd":
            one = _zstd_one_frame(data, uncompressed_size)
            if one is not None:
                raw = one
            else:  # several frames, or a frame that claims another size: read with a bound
                import zstandard  # on first use: a process loads only the codecs its files need

                with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True) as r:
                    raw = _read_bounded(r, uncompressed_size + 1)
        elif compression == "lz4":
            import lz4.frame  # on first use: a process loads only the codecs its files need

            raw = lz4.frame.LZ4FrameDecompressor().decompress(bytes(data), max_length=uncompressed_size + 1)
        else:
            raise DecompressionError(f"unsupported compression {compression!r} (pendsim reads zstd, lz4, none)")
    except DecompressionError:
        raise
    except Exception as exc:  # zstd.ZstdError, RuntimeError from lz4, ...: damaged stream
        raise DecompressionError(f"{compression} stream is damaged ({type(exc).__name__}: {exc})") from None
    if len(raw) != uncompressed_size:
        raise DecompressionError(
            f"chunk inflates to {'more than ' if len(raw) > uncompressed_size else ''}"
            f"{len(raw)} bytes, not the declared {uncompressed_size}"
        )
    return raw


def _zstd_one_frame(data: bytes | memoryview, uncompressed_size: int) -> bytes | None:
    """A chunk that is one zstd frame declaring ``uncompressed_size`` (or no size), inflated in one
    call (5x faster than the stream reader: no 1 MB reads joined); None for anything else (several
    frames, another declared size, a damaged frame): the caller then reads the stream with a bound.
    The output never exceeds ``uncompressed_size``: the frame's declared size is checked first
    (zstd allocates what the frame declares), and a frame without one is capped."""
    import zstandard  # on first use: a process loads only the codecs its files need

    try:
        declared = zstandard.frame_content_size(data)
        if declared not in (uncompressed_size, -1):
            return None
        return zstandard.ZstdDecompressor().decompress(
            data, max_output_size=max(uncompressed_size, 1), allow_extra_data=False
        )
    except zstandard.ZstdError:
        return None


def _read_bounded(reader: Any, limit: int) -> bytes:
    parts: list[bytes] = []
    total = 0
    while total < limit:
        block = reader.read(min(1 << 20, limit - total))
        if not block:
            break
        parts.append(block)
        total += len(block)
    return b"".join(parts)


def compressor(name: str):
    """(Chunk.compression string, compress function or None) for an option name."""
    if name == "zstd":
        import zstandard  # on first use: a process loads only the codecs its files need

        return "zstd", zstandard.ZstdCompressor(level=3).compress
    if name == "lz4":
        import lz4.frame  # on first use: a process loads only the codecs its files need

        return "lz4", lz4.frame.compress
    if name == "none":
        return "", None
    raise ValueError(f"unknown compression {name!r}; allowed: {', '.join(COMPRESSIONS)}")


def message_index_record(channel_id: int, log_time_ns: np.ndarray, offsets: np.ndarray) -> bytes:
    """A MessageIndex record: one (log time, offset in the uncompressed chunk) per message."""
    entries = np.empty(len(log_time_ns), dtype=INDEX_ENTRY)
    entries["timestamp"] = log_time_ns
    entries["offset"] = offsets
    body = entries.tobytes()
    return MESSAGE_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 2 + 4 + len(body), channel_id, len(body)) + body


__all__ = [
    "CHUNK_HEAD",
    "COMPRESSIONS",
    "INDEX_ENTRY",
    "MCAP_MAGIC",
    "MESSAGE_PREFIX",
    "MESSAGE_PREFIX_SIZE",
    "DecompressionError",
    "decompress",
]
