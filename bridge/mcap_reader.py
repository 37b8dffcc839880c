"""Read an MCAP file in one pass into numpy arrays per channel, recovering what a crash left.

The reader walks the file record by record from the start (it does not need the summary), so a
file cut off by a crash yields every message up to its last complete chunk. Chunks are checked
against their CRC and decompressed whole; a chunk whose messages all have one channel and one
size (as ``BulkMcapWriter`` writes them) becomes an (n, size) array with no per-message Python
work. Other files are read too, message by message.
"""

from __future__ import annotations

import dataclasses
import io
import mmap
import struct
import zlib
from collections import defaultdict
from collections.abc import Callable, Collection
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Metadata, Schema

from bridge.mcap_writer import MCAP_MAGIC
from pendsim_mj.errors import RecordingError

_MESSAGE_PREFIX = struct.Struct("<BQHIQQ")  # opcode, length, channel, sequence, log_time, publish_time
_CHUNK_HEAD = struct.Struct("<QQQI")  # start, end, uncompressed size, uncompressed crc


@dataclasses.dataclass
class ChannelData:
    """All messages of one channel, in log-time order.

    Attributes:
      log_time_ns: (n,) int64.
      publish_time_ns: (n,) int64.
      payloads: (n, size) uint8 when every message has one size, else a list of bytes.
    """

    log_time_ns: np.ndarray
    publish_time_ns: np.ndarray
    payloads: np.ndarray | list[bytes]

    def __len__(self) -> int:
        return len(self.log_time_ns)


@dataclasses.dataclass
class McapContents:
    """What a pass over an MCAP file found.

    Attributes:
      path: the file.
      schemas, channels: by id (``mcap.records`` objects).
      messages: ChannelData by channel id.
      metadata: name -> dict of strings.
      attachments: name -> Attachment record.
      complete: the file ended with a footer and the closing magic.
      problems: what stopped or disturbed the read (truncation, bad chunks), in words.
      bytes_read: offset up to which the file was understood.
      file_size: bytes in the file.
      chunks: chunks read.
    """

    path: Path
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    messages: dict[int, ChannelData]
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, Attachment]
    complete: bool
    problems: list[str]
    bytes_read: int
    file_size: int
    chunks: int

    @property
    def message_count(self) -> int:
        return sum(len(m) for m in self.messages.values())

    def topic(self, name: str) -> ChannelData:
        """The messages of the channel with this topic; RecordingError if there is none."""
        for cid, channel in self.channels.items():
            if channel.topic == name:
                return self.messages.get(cid) or ChannelData(np.zeros(0, np.int64), np.zeros(0, np.int64), [])
        raise RecordingError(f"{self.path}: no topic {name!r}; topics: {', '.join(sorted(self.topics()))}")

    def topics(self) -> dict[str, int]:
        """topic -> message count."""
        return {ch.topic: len(self.messages.get(cid, ())) for cid, ch in self.channels.items()}

    def summary_line(self) -> str:
        """How much was recovered, for error messages."""
        t_end = max((int(m.log_time_ns[-1]) for m in self.messages.values() if len(m)), default=0)
        return (
            f"recovered {self.message_count} messages in {self.chunks} chunks up to log time {t_end / 1e9:.3f} s "
            f"({self.bytes_read} of {self.file_size} bytes)"
        )


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise ValueError(f"unsupported compression {compression!r}")


def _record(cls, content: bytes):
    return cls.read(ReadDataStream(io.BytesIO(content)))


class _Accumulator:
    def __init__(self) -> None:
        self.blocks: dict[int, list] = defaultdict(list)  # channel -> [(log, pub, payloads)]

    def add_fixed(self, channel: int, log: np.ndarray, pub: np.ndarray, payloads: np.ndarray) -> None:
        self.blocks[channel].append((log, pub, payloads))

    def add_one(self, channel: int, log: int, pub: int, payload: bytes) -> None:
        self.blocks[channel].append((np.array([log], np.int64), np.array([pub], np.int64), [payload]))

    def result(self) -> dict[int, ChannelData]:
        out = {}
        for channel, blocks in self.blocks.items():
            log = np.concatenate([b[0] for b in blocks]).astype(np.int64)
            pub = np.concatenate([b[1] for b in blocks]).astype(np.int64)
            sizes = {b[2].shape[1] if isinstance(b[2], np.ndarray) else len(b[2][0]) for b in blocks}
            if len(sizes) == 1:
                size = sizes.pop()
                payloads = np.concatenate(
                    [
                        b[2] if isinstance(b[2], np.ndarray) else np.frombuffer(b[2][0], np.uint8).reshape(1, size)
                        for b in blocks
                    ]
                )
            else:
                payloads = [bytes(p) for b in blocks for p in b[2]]  # rows of an array or bytes
            order = np.argsort(log, kind="stable")
            if np.any(order != np.arange(len(order))):
                log, pub = log[order], pub[order]
                payloads = payloads[order] if isinstance(payloads, np.ndarray) else [payloads[i] for i in order]
            out[channel] = ChannelData(log, pub, payloads)
        return out


def _parse_chunk_messages(raw: bytes, acc: _Accumulator) -> None:
    """Messages of one uncompressed chunk: in bulk when they share one channel and size."""
    if len(raw) >= _MESSAGE_PREFIX.size:
        opcode, length, channel, _, _, _ = _MESSAGE_PREFIX.unpack_from(raw, 0)
        record = 9 + length
        if opcode == Opcode.MESSAGE and length >= 22 and len(raw) % record == 0:
            rows = np.frombuffer(raw, np.uint8).reshape(-1, record)
            head = (
                rows[:, :31]
                .copy()
                .view(
                    np.dtype(
                        [("op", "u1"), ("len", "<u8"), ("ch", "<u2"), ("seq", "<u4"), ("log", "<u8"), ("pub", "<u8")]
                    )
                )[:, 0]
            )
            if np.all(head["op"] == Opcode.MESSAGE) and np.all(head["len"] == length) and np.all(head["ch"] == channel):
                acc.add_fixed(channel, head["log"].astype(np.int64), head["pub"].astype(np.int64), rows[:, 31:])
                return
    offset = 0
    while offset + 9 <= len(raw):
        opcode, length = struct.unpack_from("<BQ", raw, offset)
        if opcode == Opcode.MESSAGE:
            _, _, channel, _, log, pub = _MESSAGE_PREFIX.unpack_from(raw, offset)
            acc.add_one(channel, log, pub, raw[offset + 31 : offset + 9 + length])
        offset += 9 + length


def read_mcap(
    path: str | Path,
    *,
    strict: bool = False,
    topics: Collection[str] | None = None,
    progress: Callable[[int], None] | None = None,
) -> McapContents:
    """Read every message, schema, channel, metadata and attachment record of an MCAP file.

    Args:
      path: the file.
      strict: raise RecordingError if the file is incomplete or damaged (naming the file and how
        much was recovered) instead of returning what could be read.
      topics: read only the messages of these topics; a chunk whose message index names only
        other channels is skipped without being decompressed.
      progress: called with the number of bytes passed after each record.

    Raises:
      RecordingError: missing file, not an MCAP file, or (strict) incomplete or damaged.
    """
    path = Path(path)
    try:
        f = open(path, "rb")  # noqa: SIM115
    except OSError as exc:
        raise RecordingError(f"{path}: cannot open: {exc.strerror}") from None
    with f:
        size = path.stat().st_size
        if size < len(MCAP_MAGIC) or f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise RecordingError(f"{path}: not an MCAP file (no MCAP magic at the start; {size} bytes)")
        buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
        try:
            return _scan(path, buf, size, strict, None if topics is None else set(topics), progress)
        finally:
            if isinstance(buf, mmap.mmap):
                buf.close()


_PARALLEL_CHUNKS = 64  # chunks decompressed at once on the thread pool


def _unpack_chunk(job: tuple[int, str, bytes, int, int]) -> bytes | Exception:
    """Decompress and CRC-check one chunk (zstd, lz4 and zlib release the GIL)."""
    _, compression, data, usize, ucrc = job
    try:
        raw = _decompress(compression, data, usize)
        if len(raw) != usize or (ucrc and zlib.crc32(raw) != ucrc):
            raise ValueError("CRC or size mismatch")
        return raw
    except Exception as exc:
        return exc


def _flush_chunks(pending: list, acc: _Accumulator, problems: list[str], pool: ThreadPoolExecutor) -> int:
    """Decompress the pending chunks in parallel and parse them in file order; returns how many."""
    read = 0
    for job, raw in zip(pending, pool.map(_unpack_chunk, pending), strict=True):
        if isinstance(raw, Exception):
            problems.append(f"damaged record at byte {job[0]} (opcode 0x06): {type(raw).__name__}: {raw}")
            continue
        _parse_chunk_messages(raw, acc)
        read += 1
    pending.clear()
    return read


def _indexed_channels(buf, offset: int, size: int) -> set[int] | None:
    """Channel ids of the message index records right after a chunk (None if there are none)."""
    channels: set[int] = set()
    while offset + 9 + 2 <= size:
        opcode, length = struct.unpack_from("<BQ", buf, offset)
        if opcode != Opcode.MESSAGE_INDEX:
            break
        channels.add(struct.unpack_from("<H", buf, offset + 9)[0])
        offset += 9 + length
    return channels or None


def _skip_chunk(buf, after: int, size: int, channels: dict[int, Channel], topics: set[str]) -> bool:
    indexed = _indexed_channels(buf, after, size)
    if indexed is None or not indexed <= channels.keys():
        return False  # unknown contents: read it
    return not any(channels[c].topic in topics for c in indexed)


def _scan(path: Path, buf, size: int, strict: bool, topics: set[str] | None, progress) -> McapContents:
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: dict[str, dict[str, str]] = {}
    attachments: dict[str, Attachment] = {}
    problems: list[str] = []
    acc = _Accumulator()
    offset = len(MCAP_MAGIC)
    complete = False
    chunks = 0
    pending: list[tuple[int, str, bytes, int, int]] = []
    pool = ThreadPoolExecutor(max_workers=2)
    while True:
        if offset + 9 > size:
            problems.append(f"file ends inside the data section at byte {offset} (truncated: no footer)")
            break
        opcode, length = struct.unpack_from("<BQ", buf, offset)
        body_start, body_end = offset + 9, offset + 9 + length
        if body_end > size:
            problems.append(
                f"record at byte {offset} (opcode 0x{opcode:02x}) needs {length} bytes; the file ends first"
            )
            break
        if opcode == Opcode.FOOTER:
            complete = buf[body_end : body_end + len(MCAP_MAGIC)] == MCAP_MAGIC
            if not complete:
                problems.append("footer without the closing magic")
            offset = body_end + len(MCAP_MAGIC)
            break
        content = bytes(buf[body_start:body_end]) if opcode != Opcode.CHUNK else None
        try:
            if opcode == Opcode.SCHEMA:
                s = _record(Schema, content)
                schemas[s.id] = s
            elif opcode == Opcode.CHANNEL:
                c = _record(Channel, content)
                channels[c.id] = c
            elif opcode == Opcode.MESSAGE:
                _, _, channel, _, log, pub = _MESSAGE_PREFIX.unpack_from(buf, offset)
                acc.add_one(channel, log, pub, bytes(buf[offset + 31 : body_end]))
            elif opcode == Opcode.CHUNK and topics is not None and _skip_chunk(buf, body_end, size, channels, topics):
                pass
            elif opcode == Opcode.CHUNK:
                _, _, usize, ucrc = _CHUNK_HEAD.unpack_from(buf, body_start)
                p = body_start + _CHUNK_HEAD.size
                (clen,) = struct.unpack_from("<I", buf, p)
                compression = bytes(buf[p + 4 : p + 4 + clen]).decode()
                p += 4 + clen
                (dlen,) = struct.unpack_from("<Q", buf, p)
                pending.append((offset, compression, bytes(buf[p + 8 : p + 8 + dlen]), usize, ucrc))
                if len(pending) >= _PARALLEL_CHUNKS:
                    chunks += _flush_chunks(pending, acc, problems, pool)
            elif opcode == Opcode.METADATA:
                m = _record(Metadata, content)
                metadata[m.name] = dict(m.metadata)
            elif opcode == Opcode.ATTACHMENT:
                a = _record(Attachment, content)
                attachments[a.name] = a
            elif opcode == Opcode.DATA_END:
                pass  # the summary repeats what the data section held
        except Exception as exc:  # a damaged record: note it, skip it by its length, go on
            problems.append(f"damaged record at byte {offset} (opcode 0x{opcode:02x}): {type(exc).__name__}: {exc}")
        if progress is not None:
            progress(body_end - offset)
        offset = body_end
    chunks += _flush_chunks(pending, acc, problems, pool)
    pool.shutdown()
    messages = acc.result()
    if topics is not None:
        messages = {cid: data for cid, data in messages.items() if cid in channels and channels[cid].topic in topics}
    contents = McapContents(
        path=path,
        schemas=schemas,
        channels=channels,
        messages=messages,
        metadata=metadata,
        attachments=attachments,
        complete=complete and not problems,
        problems=problems,
        bytes_read=min(offset, size),
        file_size=size,
        chunks=chunks,
    )
    if strict and not contents.complete:
        raise RecordingError(
            f"{path}: {problems[0] if problems else 'incomplete'}; {contents.summary_line()}. "
            f"'pendsim recover {path} FIXED.mcap' rewrites the readable part"
        )
    return contents
