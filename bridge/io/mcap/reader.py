"""Read and verify an MCAP file: every CRC, every summary record against the data section, and
the messages chunk by chunk into numpy arrays.

Two passes over a memory map of the file:

1. **Structure** (``scan_mcap``): walk the records from the start (no summary needed, so a file
   cut off by a crash is read up to its last complete record). Checked: the magic at both ends,
   every record's framing, each attachment's CRC, the data-section CRC in DataEnd, the summary
   CRC in the footer, and that the summary (schemas, channels, statistics, chunk, attachment and
   metadata indexes, summary offsets) matches the data section's own records; a summary copy
   never overrides the original. Bytes after the closing magic (garbage, a second MCAP file)
   are reported. After a damaged record the walk resynchronises on the next chunk whose framing
   is consistent and whose CRC checks, so every intact chunk after the damage is kept.
2. **Messages** (``McapFile.chunks``): chunks are inflated (with a size and ratio cap, a few
   ahead on one pool thread while this one parses), checked against their CRC, and their
   messages parsed with numpy through the message index that follows each chunk (whose
   offsets are checked to tile the chunk exactly); the messages of one channel and size become
   an (n, size) array. A consumer sees one chunk at a time: nothing holds all payloads unless
   it keeps them (``read_mcap`` does; ``recording.read_recording`` decodes them into per-field
   arrays as they come).

Everything found wrong is a *problem*, phrased with the region and byte offset; ``strict``
readers raise ``RecordingError`` on the first. Content that no CRC covers (metadata and
schemas outside chunks in a file without DataEnd, or whose writer left the CRC at 0) is listed
in ``unverified``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import itertools
import mmap
import os
import stat
import zlib
from collections import defaultdict, deque
from collections.abc import Callable, Collection, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from pendsim_mj.errors import RecordingError

from .records import (
    CHUNK_HEAD,
    FOOTER_SIZE,
    INDEX_ENTRY,
    MCAP_MAGIC,
    MESSAGE_FIELDS,
    MESSAGE_PREFIX,
    MESSAGE_PREFIX_SIZE,
    RECORD_HEAD,
    SUMMARY_OPCODES,
    DecompressionError,
    check_inflation,
    decompress,
    import_hint,
)
from .writer import METADATA_CRC_KEY, metadata_crc

_COMPRESSIONS = ("", "zstd", "lz4")
UNCHUNKED = "a message outside chunks (pendsim reads chunked files only)"
INFLATE_AHEAD = 2
"""Chunks inflated ahead of the one being parsed (``McapFile.chunks``): more was measured no faster."""


@dataclasses.dataclass
class ChannelData:
    """Messages of one channel, in log-time order.

    Attributes:
      log_time_ns: (n,) int64.
      publish_time_ns: (n,) int64.
      payloads: (n, size) uint8 when every message has one size, else a list of bytes.
    """

    log_time_ns: NDArray[np.int64]
    publish_time_ns: NDArray[np.int64]
    payloads: NDArray[np.uint8] | list[bytes]

    def __len__(self) -> int:
        return len(self.log_time_ns)


@dataclasses.dataclass(frozen=True)
class Unverified:
    """Content of a file that no CRC covers (kind: metadata, attachment, schema, channel, chunk)."""

    kind: str
    name: str  # metadata/attachment name, schema/channel id, or the chunk's byte offset
    offset: int

    def __str__(self) -> str:
        return f"{self.kind} {self.name} at byte {self.offset} (no CRC covers it)"


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


@dataclasses.dataclass(frozen=True)
class ChunkMessages:
    """The messages of one chunk, by channel (each in log-time order)."""

    chunk: ChunkRef
    channels: dict[int, ChannelData]


@dataclasses.dataclass
class McapFile:
    """The structure of an MCAP file (pass 1) and a way to walk its chunks (pass 2).

    Attributes:
      path: the file.
      file_size: bytes.
      schemas, channels: by id, the data section's own records (chunks' included once read;
        the summary's only where the data section has none).
      metadata: name -> entries (without the CRC entry pendsim adds).
      attachments: name -> Attachment record (CRC checked).
      chunk_refs: every chunk found, in file order.
      problems: what is wrong, one phrase each naming the region and byte offset.
      unverified: content no CRC covers, in words.
      complete: the file has DataEnd, summary and footer, all consistent, and nothing after.
      bytes_read: the offset up to which the file was understood.
      statistics: the summary's Statistics record, if any.
    """

    path: Path
    file_size: int
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, Attachment]
    chunk_refs: list[ChunkRef]
    problems: list[str]
    unverified: list[Unverified]
    complete: bool
    bytes_read: int
    statistics: Statistics | None
    _buf: Any = dataclasses.field(repr=False, default=None)
    _summary_channels: dict[int, Channel] = dataclasses.field(repr=False, default_factory=dict)
    _summary_schemas: dict[int, Schema] = dataclasses.field(repr=False, default_factory=dict)
    chunks_read: int = 0
    _defined: set[tuple[str, int]] = dataclasses.field(repr=False, default_factory=set)  # by the data section

    def chunks(
        self,
        *,
        channels: Collection[int] | None = None,
        progress: Callable[[int], None] | None = None,
        verified_only: bool = False,
        compiled: bool = False,
    ) -> Iterator[ChunkMessages]:
        """Inflate, check and parse the chunks in file order, each chunk's pages of the memory map
        released once read. The next ``INFLATE_AHEAD`` chunks are inflated and CRC-checked on one
        pool thread (zstd and zlib's crc32 release the GIL) while this thread parses: reading a
        6 h recording's IMU topics took 1.4-1.7 s instead of 2.8-2.9 s on an idle 2-core machine,
        and the same 2.6-2.7 s with the other core busy. The thread ends when the walk does
        (also when the consumer stops early).

        Args:
          channels: only chunks whose index names one of these channels (None: all), and only
            these channels' messages; chunks without an index are always read.
          progress: called with the bytes of each chunk passed.
          verified_only: skip chunks without a CRC.
          compiled: check each chunk's message index with the compiled kernel
            (``chunk_kernel``: a chunk in a quarter of numpy's time, the same messages; numba is
            imported, and its first call in a process costs 0.3-0.5 s).
        Yields:
          One ChunkMessages per intact chunk; a damaged chunk is added to ``problems`` and skipped.
        """
        wanted = None if channels is None else set(channels)
        refs = [r for r in self.chunk_refs if wanted is None or not r.index or wanted & r.index.keys()]
        if verified_only:
            refs = [r for r in refs if r.uncompressed_crc]
        if progress is not None and len(refs) < len(self.chunk_refs):
            progress(sum(r.length for r in self.chunk_refs) - sum(r.length for r in refs))
        buf = self._buf
        fast = _CompiledIndex(*np.full((2, 1 << 16), -1, np.int64)) if compiled else None
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="mcap-inflate") as pool:
            pending: deque[tuple[ChunkRef, Future[bytes | Exception]]] = deque()
            upcoming = iter(refs)
            try:
                for ref in itertools.islice(upcoming, INFLATE_AHEAD):
                    pending.append((ref, pool.submit(_inflate, buf, ref)))
                while pending:
                    ref, inflating = pending.popleft()
                    following = next(upcoming, None)
                    if following is not None:
                        pending.append((following, pool.submit(_inflate, buf, following)))
                    raw = inflating.result()
                    if progress is not None:
                        progress(ref.length)
                    if isinstance(raw, Exception):
                        _release(buf, ref.offset, ref.offset + ref.length)
                        self.problems.append(f"chunk at byte {ref.offset}: {raw}")
                        continue
                    parsed = self._parse_chunk(ref, raw, wanted, fast)
                    del raw
                    # the chunk and its message index records (as large as the chunk's messages'
                    # data for small messages) leave resident memory once parsed
                    ends = (o + n for o, n in ref.index.values())
                    _release(buf, ref.offset, max([ref.offset + ref.length, *ends]))
                    if parsed is not None:
                        self.chunks_read += 1
                        yield parsed
            finally:  # a consumer that stops early: no inflation left running on the map
                for _, inflating in pending:
                    inflating.cancel()

    def _parse_chunk(
        self, ref: ChunkRef, raw: bytes, channels: Collection[int] | None = None, fast: _CompiledIndex | None = None
    ) -> ChunkMessages | None:
        try:
            parsed = _messages_compiled(raw, self._buf, ref, fast, channels) if fast is not None and ref.index else None
            records, messages = parsed or _chunk_messages(raw, _read_index(self._buf, ref), channels)
        except ValueError as exc:
            self.problems.append(f"chunk at byte {ref.offset}: {exc}")
            return None
        for record in records:
            self._add_definition(record, f"chunk at byte {ref.offset}", ref.uncompressed_crc)
        return ChunkMessages(ref, messages)

    def _add_definition(self, record: Schema | Channel, where: str, ref_crc: int = 0) -> None:
        store: dict[Any, Any] = self.schemas if isinstance(record, Schema) else self.channels
        kind = type(record).__name__
        old = store.get(record.id) if (kind, record.id) in self._defined else None
        self._defined.add((kind, record.id))
        if old is not None and old != record:
            self.problems.append(f"{where}: {kind} {record.id} differs from the one defined before")
            return
        store[record.id] = record
        if ref_crc:
            self.unverified[:] = [u for u in self.unverified if (u.kind, u.name) != (kind.lower(), str(record.id))]
        summary = (self._summary_schemas if isinstance(record, Schema) else self._summary_channels).get(record.id)
        if summary is not None and summary != record:
            self.problems.append(f"summary: {kind} {record.id} differs from the data section's ({where})")

    @property
    def message_count_indexed(self) -> int:
        return sum(r.index_count(c) for r in self.chunk_refs for c in r.index)

    def channel_ids(self, topics: Collection[str]) -> set[int]:
        """Ids of the channels with these topics (as far as the file has defined them)."""
        known = {**self._summary_channels, **self.channels}
        return {cid for cid, ch in known.items() if ch.topic in topics}

    def close(self) -> None:
        """Release the memory map. While an array still views it (an exception, e.g. Ctrl-C,
        unwinding through a frame that holds one), the map is left to close itself when the
        last view goes."""
        if self._buf is not None:
            with contextlib.suppress(BufferError):
                self._buf.close()
            self._buf = None

    def error_text(self, readable: str | None = None) -> str:
        """One line naming the first problem and how much is readable."""
        more = f" (and {len(self.problems) - 1} more problems)" if len(self.problems) > 1 else ""
        if not self.chunk_refs and UNCHUNKED in self.problems[0]:  # a valid file of another layout
            return f"{self.path}: {self.problems[0]}; write it with chunks (every MCAP writer's default layout)"
        if not self.chunk_refs:  # not one complete chunk: nothing a rewrite could keep
            return f"{self.path}: {self.problems[0]}{more}; no complete chunk of messages, nothing to recover"
        return (
            f"{self.path}: {self.problems[0]}{more}; {readable or self.readable_line()}. "
            f"'pendsim recover {self.path} FIXED.mcap' rewrites the readable part"
        )

    def readable_line(self) -> str:
        """How much of the file is readable: the chunks that inflate and pass their CRC (each
        inflated once more here, on the way to an error: a damaged chunk is not counted even when
        only the data section's CRC found the damage), their messages as their indexes list them."""
        intact = []
        for ref in self.chunk_refs:
            if self._buf is None or not isinstance(_inflate(self._buf, ref), Exception):
                intact.append(ref)
            if self._buf is not None:
                _release(self._buf, ref.offset, ref.offset + ref.length)
        n = sum(r.index_count(c) for r in intact for c in r.index)
        t0 = min((r.start_ns for r in intact), default=0)
        t_end = max((r.end_ns for r in intact), default=0)
        return (
            f"{n} messages in {len(intact)} chunks intact, {(t_end - t0) / 1e9:.3f} s of log time "
            f"({self.bytes_read} of {self.file_size} bytes)"
        )


def _inflate(buf: Any, ref: ChunkRef) -> bytes | Exception:
    """Inflate and CRC-check one chunk (zstd, lz4 and zlib release the GIL)."""
    try:
        raw = decompress(ref.compression, buf[ref.data_start : ref.data_start + ref.data_size], ref.uncompressed_size)
        if ref.uncompressed_crc and zlib.crc32(raw) != ref.uncompressed_crc:
            raise DecompressionError("CRC mismatch: the chunk's records are damaged")
        return raw
    except DecompressionError as exc:
        return exc


def _read_index(buf: Any, ref: ChunkRef) -> dict[int, NDArray] | None:
    """The chunk's message index entries per channel (None if it has no index)."""
    if not ref.index:
        return None
    out = {}
    for channel, (offset, length) in ref.index.items():
        body = offset + RECORD_HEAD.size + 6
        out[channel] = np.frombuffer(buf, dtype=INDEX_ENTRY, count=(length - RECORD_HEAD.size - 6) // 16, offset=body)
    return out


def _chunk_messages(
    raw: bytes, index: dict[int, NDArray] | None, channels: Collection[int] | None = None
) -> tuple[list, dict[int, ChannelData]]:
    """Schema/Channel records and messages (per channel; only ``channels``' unless None) of an
    uncompressed chunk. Every message's framing is checked, whichever channels are kept."""
    data = np.frombuffer(raw, dtype=np.uint8)
    if index is not None and any(len(e) for e in index.values()):
        parsed = _messages_by_index(raw, data, index, channels)
        if parsed is not None:
            return parsed
    return _messages_by_walking(raw, channels)


def _messages_by_index(
    raw: bytes, data: NDArray[np.uint8], index: dict[int, NDArray], channels: Collection[int] | None = None
):
    """Parse with the message index, in bulk; None unless the index tiles the chunk exactly."""
    channel = np.concatenate([np.full(len(e), c, np.int64) for c, e in index.items()])
    entries = np.concatenate(list(index.values()))
    offsets = entries["offset"].astype(np.int64)
    order = np.argsort(offsets, kind="stable")
    offsets, channel, stamps = offsets[order], channel[order], entries["timestamp"][order]
    first = int(offsets[0])
    if first < 0 or int(offsets[-1]) + MESSAGE_PREFIX_SIZE > len(raw):
        return None
    records = _definitions_up_to(raw, first)
    if records is None:
        return None
    prefix = sliding_window_view(data, MESSAGE_PREFIX_SIZE)[offsets].copy().view(MESSAGE_PREFIX).reshape(-1)
    ends = offsets + RECORD_HEAD.size + prefix["length"].astype(np.int64)
    if not (
        np.all(prefix["opcode"] == Opcode.MESSAGE)
        and np.all(prefix["channel"] == channel)
        and np.all(prefix["log_time"] == stamps)
        and np.all(ends[:-1] == offsets[1:])
        and ends[-1] == len(raw)
        and np.all(prefix["length"] >= MESSAGE_FIELDS.size)
    ):
        return None
    return list(records), _group(data, offsets, prefix, channels)


def _definitions_up_to(raw: bytes, first: int) -> tuple[Schema | Channel, ...] | None:
    """The Schema and Channel records before a chunk's first message at ``first``; None unless
    they end exactly there."""
    try:
        records, at = _leading_definitions(raw[:first])
    except ValueError:
        return None
    return records if at == first else None


@functools.lru_cache(maxsize=16)
def _leading_definitions(head: bytes) -> tuple[tuple[Schema | Channel, ...], int]:
    """``_definitions`` of a chunk's leading bytes, parsed once for chunks that repeat them (a
    writer that defines its schemas and channels in every chunk)."""
    records, at = _definitions(head, 0, len(head))
    return tuple(records), at


def _group(
    data: NDArray[np.uint8], offsets: NDArray[np.int64], prefix: NDArray, channels: Collection[int] | None = None
) -> dict[int, ChannelData]:
    out: dict[int, ChannelData] = {}
    sizes = prefix["length"].astype(np.int64) - MESSAGE_FIELDS.size
    of_message = prefix["channel"].astype(np.int64)
    present = np.unique(of_message) if channels is None else sorted(channels)
    for c in present:
        at = np.flatnonzero(of_message == c)
        if not len(at):
            continue
        log = prefix["log_time"][at].astype(np.int64)
        pub = prefix["publish_time"][at].astype(np.int64)
        out[int(c)] = _channel_data(data, offsets[at], log, pub, sizes[at])
    return out


def _channel_data(
    data: NDArray[np.uint8], offsets: NDArray[np.int64], log: NDArray[np.int64], pub: NDArray[np.int64], size: NDArray
) -> ChannelData:
    """One channel's messages of a chunk (offsets of their records in chunk order, their log and
    publish times and data sizes, (k,) each) as ChannelData: messages of one size as an (k, size)
    array, in log-time order."""
    payloads: NDArray[np.uint8] | list[bytes]
    if np.all(size == size[0]):
        width = int(size[0])
        start = offsets + MESSAGE_PREFIX_SIZE
        payloads = sliding_window_view(data, width)[start] if width else np.zeros((len(offsets), 0), np.uint8)
    else:
        payloads = [
            data[o + MESSAGE_PREFIX_SIZE : o + MESSAGE_PREFIX_SIZE + s].tobytes()
            for o, s in zip(offsets, size, strict=True)
        ]
    if np.any(np.diff(log) < 0):  # a chunk from another writer need not be sorted
        order = np.argsort(log, kind="stable")
        log, pub = log[order], pub[order]
        payloads = payloads[order] if isinstance(payloads, np.ndarray) else [payloads[i] for i in order]
    return ChannelData(log, pub, payloads)


def _messages_compiled(
    raw: bytes, buf: Any, ref: ChunkRef, compiled: _CompiledIndex, channels: Collection[int] | None = None
) -> tuple[list, dict[int, ChannelData]] | None:
    """``_messages_by_index`` in one compiled pass (``chunk_kernel.index_messages``): the same
    records and messages, or None where the kernel does not accept the chunk (the caller then
    parses it with numpy, which names what is wrong)."""
    from . import chunk_kernel

    low = min(o for o, _ in ref.index.values())
    high = max(o + n for o, n in ref.index.values())
    index_bytes = np.frombuffer(buf, np.uint8, count=high - low, offset=low)  # the chunk's MessageIndex records
    spans = np.array(
        [(c, o - low + RECORD_HEAD.size + 6, ref.index_count(c)) for c, (o, _) in ref.index.items()], np.int64
    ).reshape(-1, 3)
    wanted = sorted(c for c in ref.index if channels is None or c in channels)
    capacity = max([1, *(ref.index_count(c) for c in wanted)])
    found = np.empty((4, len(wanted), capacity), np.int64)  # offsets, log times, publish times, sizes
    counts = np.zeros(len(wanted), np.int64)
    data = np.frombuffer(raw, np.uint8)
    compiled.slot[wanted] = np.arange(len(wanted))
    compiled.row_of[spans[:, 0]] = np.arange(len(spans))  # ref.index: one record per channel
    try:
        offsets, log, publish, sizes = found
        slot, row_of = compiled.slot, compiled.row_of
        first = chunk_kernel.index_messages(
            data, index_bytes, spans, slot, row_of, offsets, log, publish, sizes, counts
        )
    finally:
        compiled.slot[wanted] = -1
        compiled.row_of[spans[:, 0]] = -1
        del index_bytes  # no view of the memory map outlives the call
    records = _definitions_up_to(raw, first) if first >= 0 else None
    if records is None:
        return None
    messages = {}
    for row, c in enumerate(wanted):
        k = int(counts[row])
        if k:
            messages[c] = _channel_data(data, *(f[row, :k] for f in found))
    return list(records), messages


@dataclasses.dataclass(frozen=True)
class _CompiledIndex:
    """``_messages_compiled``'s tables by channel id, (65536,) each, -1 between chunks (set and
    reset for each chunk): the output row of each wanted channel, and the row of each channel's
    MessageIndex record (``chunk_kernel.index_messages``' slot and row_of)."""

    slot: NDArray[np.int64]
    row_of: NDArray[np.int64]


def _definitions(raw: bytes, start: int, stop: int) -> tuple[list, int]:
    """Schema and Channel records in raw[start:stop]; returns them and where they end."""
    records: list[Schema | Channel] = []
    at = start
    while at < stop:
        if at + RECORD_HEAD.size > len(raw):
            raise ValueError(f"record framing broken at byte {at} of the uncompressed chunk")
        opcode, length = RECORD_HEAD.unpack_from(raw, at)
        end = at + RECORD_HEAD.size + length
        if opcode not in (Opcode.SCHEMA, Opcode.CHANNEL) or end > len(raw):
            break
        records.append(_parse(Schema if opcode == Opcode.SCHEMA else Channel, raw[at + RECORD_HEAD.size : end]))
        at = end
    return records, at


def _messages_by_walking(raw: bytes, channels: Collection[int] | None = None) -> tuple[list, dict[int, ChannelData]]:
    """Record by record (a chunk without a usable message index)."""
    data = np.frombuffer(raw, dtype=np.uint8)
    records: list[Schema | Channel] = []
    offsets: list[int] = []
    at = 0
    while at < len(raw):
        if at + RECORD_HEAD.size > len(raw):
            raise ValueError(f"record framing broken at byte {at} of the uncompressed chunk")
        opcode, length = RECORD_HEAD.unpack_from(raw, at)
        end = at + RECORD_HEAD.size + length
        if end > len(raw):
            raise ValueError(f"record at byte {at} of the uncompressed chunk runs past its end")
        if opcode == Opcode.MESSAGE:
            if length < MESSAGE_FIELDS.size:
                raise ValueError(f"message at byte {at} of the uncompressed chunk is too short")
            offsets.append(at)
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            records.append(_parse(Schema if opcode == Opcode.SCHEMA else Channel, raw[at + RECORD_HEAD.size : end]))
        else:
            raise ValueError(f"unexpected record (opcode 0x{opcode:02x}) inside the chunk")
        at = end
    if not offsets:
        return records, {}
    where = np.array(offsets, dtype=np.int64)
    prefix = sliding_window_view(data, MESSAGE_PREFIX_SIZE)[where].copy().view(MESSAGE_PREFIX).reshape(-1)
    return records, _group(data, where, prefix, channels)


def _parse(cls: Any, body: bytes | memoryview) -> Any:
    """One record from its body, which it must fill exactly."""
    stream = ReadDataStream(io.BytesIO(bytes(body)))
    try:
        record = cls.read(stream)
    except Exception as exc:  # EndOfFile, struct.error, UnicodeDecodeError: damaged
        raise ValueError(f"damaged {cls.__name__} record ({type(exc).__name__})") from None
    if stream.count != len(body):
        raise ValueError(f"damaged {cls.__name__} record (its fields fill {stream.count} of {len(body)} bytes)")
    return record


# ------------------------------------------------------------------------------------------------
# Pass 1: the structure


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


def scan_mcap(path: str | Path, *, recover: bool = True) -> McapFile:
    """Pass 1 over an MCAP file: structure, CRCs (all but the chunks'), summary against data.

    Args:
      path: the file.
      recover: after a damaged record, resynchronise on the next intact chunk (else stop there).

    Raises:
      RecordingError: the file is missing, unreadable, special, or does not start with the
        MCAP magic. Everything else is reported in ``problems``.
    """
    path = Path(path)
    buf, size = open_map(path)
    if buf[: len(MCAP_MAGIC)] != MCAP_MAGIC:
        buf.close()
        raise RecordingError(f"{path}: not an MCAP file (no MCAP magic at the start; {size} bytes){import_hint(path)}")
    return _Scanner(path, buf, size, recover).run()


class _Scanner:
    def __init__(self, path: Path, buf: Any, size: int, recover: bool) -> None:
        self.path, self.buf, self.size, self.recover = path, buf, size, recover
        self.problems: list[str] = []
        self.unverified: list[Unverified] = []
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.metadata_at: dict[int, tuple[int, str, bool]] = {}  # offset -> (length, name, self-verified)
        self.attachments: dict[str, Attachment] = {}
        self.attachment_at: dict[int, tuple[int, Attachment]] = {}
        self.chunks: list[ChunkRef] = []
        self.outside: list[Unverified] = []  # schemas/channels outside chunks
        self.data_end_at: int | None = None
        self.data_crc_ok = False

    def run(self) -> McapFile:
        offset = self._header()
        end = offset or len(MCAP_MAGIC)
        reached_end = False
        while offset is not None and not reached_end:
            offset, reached_end = self._data_record(offset)
            end = offset if offset is not None else end
        complete = False
        statistics = None
        summary_channels: dict[int, Channel] = {}
        summary_schemas: dict[int, Schema] = {}
        if reached_end and offset is not None:
            summary = self._summary(offset)
            if summary is not None:
                statistics, summary_schemas, summary_channels, end = summary
                complete = not self.problems
        self._note_unverified()
        mf = McapFile(
            path=self.path,
            file_size=self.size,
            schemas=self.schemas,
            channels=self.channels,
            metadata=self.metadata,
            attachments=self.attachments,
            chunk_refs=self.chunks,
            problems=self.problems,
            unverified=self.unverified,
            complete=complete,
            bytes_read=min(end, self.size),
            statistics=statistics,
            _buf=self.buf,
            _summary_channels=summary_channels,
            _summary_schemas=summary_schemas,
            _defined={("Schema", i) for i in self.schemas} | {("Channel", i) for i in self.channels},
        )
        for sid, s in summary_schemas.items():
            mf.schemas.setdefault(sid, s)
        for cid, c in summary_channels.items():
            mf.channels.setdefault(cid, c)
        return mf

    # -- data section ---------------------------------------------------------------------------
    def _header(self) -> int | None:
        at = len(MCAP_MAGIC)
        head = self._frame(at)
        if head is None or head[0] != Opcode.HEADER:
            self.problems.append(f"no Header record at byte {at} (the file is damaged or truncated)")
            return self._resync(at) if self.recover else None
        try:
            _parse(Header, self.buf[at + RECORD_HEAD.size : head[2]])
        except ValueError as exc:
            self.problems.append(f"Header at byte {at}: {exc}")
        return head[2]

    def _frame(self, at: int) -> tuple[int, int, int] | None:
        """(opcode, body start, end) of the record at ``at``, or None if it cannot fit."""
        if at + RECORD_HEAD.size > self.size:
            return None
        opcode, length = RECORD_HEAD.unpack_from(self.buf, at)
        end = at + RECORD_HEAD.size + length
        if end > self.size:
            return None
        return opcode, at + RECORD_HEAD.size, end

    def _data_record(self, at: int) -> tuple[int | None, bool]:
        """Handle the data-section record at ``at``; returns (next offset, reached DataEnd)."""
        if at == self.size:
            self.problems.append(
                f"file ends at byte {at} inside the data section (truncated: no DataEnd, summary or footer)"
            )
            return None, False
        frame = self._frame(at)
        if frame is None:
            if at + RECORD_HEAD.size > self.size:
                self.problems.append(f"file ends at byte {self.size} inside a record header at byte {at} (truncated)")
                return None, False
            opcode, length = RECORD_HEAD.unpack_from(self.buf, at)
            self.problems.append(
                f"record at byte {at} (opcode 0x{opcode:02x}) claims {length} bytes; the file ends first "
                "(truncated, or a damaged length)"
            )
            return self._after_damage(at), False
        opcode, body, end = frame
        try:
            if opcode == Opcode.CHUNK:
                self._chunk(at, body, end)
            elif opcode == Opcode.MESSAGE_INDEX:
                self._message_index(at, body, end)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                record = _parse(Schema if opcode == Opcode.SCHEMA else Channel, self.buf[body:end])
                store: dict[Any, Any] = self.schemas if opcode == Opcode.SCHEMA else self.channels
                if record.id in store and store[record.id] != record:
                    raise ValueError(f"{type(record).__name__} {record.id} differs from the one defined before")
                store[record.id] = record
                self.outside.append(Unverified(type(record).__name__.lower(), str(record.id), at))
            elif opcode == Opcode.METADATA:
                self._metadata(at, body, end)
            elif opcode == Opcode.ATTACHMENT:
                self._attachment(at, body, end)
            elif opcode == Opcode.MESSAGE:
                raise ValueError(UNCHUNKED)
            elif opcode == Opcode.DATA_END:
                self._data_end(at, body, end)
                return end, True
            elif opcode == Opcode.FOOTER:
                raise ValueError("a Footer without DataEnd")
            elif opcode == Opcode.HEADER:
                raise ValueError("a second Header")
            else:
                raise ValueError(f"unexpected record (opcode 0x{opcode:02x}) in the data section")
        except ValueError as exc:
            self.problems.append(f"record at byte {at} (opcode 0x{opcode:02x}): {exc}")
            return self._after_damage(at), False
        return end, False

    def _after_damage(self, at: int) -> int | None:
        return self._resync(at + 1) if self.recover else None

    def _resync(self, start: int) -> int | None:
        """The offset of the next chunk after ``start`` whose framing holds and whose CRC checks."""
        at = start
        opcode = bytes([Opcode.CHUNK])
        while True:
            at = self.buf.find(opcode, at)
            if at < 0:
                return None
            if self._plausible_chunk(at):
                self.problems.append(
                    f"resynchronised on an intact chunk at byte {at} (skipped {at - start + 1} damaged bytes)"
                )
                return at
            at += 1

    def _plausible_chunk(self, at: int) -> bool:
        frame = self._frame(at)
        if frame is None:
            return False
        try:
            ref = self._chunk_ref(at, frame[1], frame[2])
        except ValueError:
            return False
        return not isinstance(_inflate(self.buf, ref), Exception)

    def _chunk_ref(self, at: int, body: int, end: int) -> ChunkRef:
        if body + CHUNK_HEAD.size + 4 > end:
            raise ValueError("chunk too short for its fields")
        start_ns, end_ns, usize, ucrc = CHUNK_HEAD.unpack_from(self.buf, body)
        p = body + CHUNK_HEAD.size
        (clen,) = np.frombuffer(self.buf, "<u4", 1, p)
        if clen > 16 or p + 4 + clen + 8 > end:
            raise ValueError("chunk's compression field is damaged")
        try:
            compression = bytes(self.buf[p + 4 : p + 4 + clen]).decode()
        except UnicodeDecodeError:
            raise ValueError("chunk's compression field is damaged") from None
        if compression not in _COMPRESSIONS:
            raise ValueError(f"chunk compression {compression!r} is not one pendsim reads (zstd, lz4, none)")
        p += 4 + clen
        (dlen,) = np.frombuffer(self.buf, "<u8", 1, p)
        if p + 8 + int(dlen) != end:
            raise ValueError(f"chunk's records ({int(dlen)} bytes) do not fill its record ({end - p - 8} bytes)")
        if end_ns < start_ns:
            raise ValueError("chunk ends before it starts (message_end_time < message_start_time)")
        try:
            check_inflation(compression, int(dlen), usize)
        except DecompressionError as exc:
            raise ValueError(str(exc)) from None
        return ChunkRef(at, end - at, start_ns, end_ns, compression, p + 8, int(dlen), usize, ucrc, {})

    def _chunk(self, at: int, body: int, end: int) -> None:
        ref = self._chunk_ref(at, body, end)
        if not ref.uncompressed_crc:
            self.unverified.append(Unverified("chunk", str(at), at))
        self.chunks.append(ref)

    def _message_index(self, at: int, body: int, end: int) -> None:
        if end - body < 6:
            raise ValueError("message index too short")
        channel = int(np.frombuffer(self.buf, "<u2", 1, body)[0])
        nbytes = int(np.frombuffer(self.buf, "<u4", 1, body + 2)[0])
        if nbytes != end - body - 6 or nbytes % INDEX_ENTRY.itemsize:
            raise ValueError("message index length does not match its entries")
        if not self.chunks or channel in self.chunks[-1].index:
            raise ValueError("message index without its chunk")
        self.chunks[-1].index[channel] = (at, end - at)

    def _metadata(self, at: int, body: int, end: int) -> None:
        record = _parse(Metadata, self.buf[body:end])
        entries = dict(record.metadata)
        crc = entries.pop(METADATA_CRC_KEY, None)
        verified = False
        if crc is not None:
            if crc != f"{metadata_crc(entries):08x}":
                raise ValueError(f"metadata {record.name!r} fails its CRC (its values are damaged)")
            verified = True
        if record.name in self.metadata and self.metadata[record.name] != entries:
            raise ValueError(f"a second metadata record {record.name!r} with other values")
        self.metadata[record.name] = entries
        self.metadata_at[at] = (end - at, record.name, verified)

    def _attachment(self, at: int, body: int, end: int) -> None:
        record = _parse(Attachment, self.buf[body:end])
        (crc,) = np.frombuffer(self.buf, "<u4", 1, end - 4)
        if crc and zlib.crc32(self.buf[body : end - 4]) != crc:
            raise ValueError(f"attachment {record.name!r} fails its CRC (its data are damaged)")
        if not crc:
            self.unverified.append(Unverified("attachment", record.name, at))
        if record.name in self.attachments and self.attachments[record.name] != record:
            raise ValueError(f"a second attachment {record.name!r} with other data")
        self.attachments[record.name] = record
        self.attachment_at[at] = (end - at, record)

    def _data_end(self, at: int, body: int, end: int) -> None:
        if end - body != 4:
            raise ValueError("DataEnd of the wrong length")
        (crc,) = np.frombuffer(self.buf, "<u4", 1, body)
        self.data_end_at = at
        if crc == 0:
            return
        if _crc32(self.buf, 0, at) != crc:
            self.problems.append(f"data section (bytes 0-{at}) fails the DataEnd CRC: some record in it is damaged")
        else:
            self.data_crc_ok = True

    def _note_unverified(self) -> None:
        if self.data_crc_ok:
            return
        for at, (_, name, verified) in sorted(self.metadata_at.items()):
            if not verified:
                self.unverified.append(Unverified("metadata", name, at))
        self.unverified += self.outside  # until a chunk with a CRC repeats them

    # -- summary and footer ---------------------------------------------------------------------
    def _summary(self, start: int):
        """Parse and check the summary and footer after DataEnd; None if they are unusable."""
        records: list[tuple[int, int, Any]] = []
        at = start
        footer_at = None
        while True:
            frame = self._frame(at)
            if frame is None:
                self.problems.append(f"summary: file ends inside a record at byte {at} (truncated: no footer)")
                return None
            opcode, body, end = frame
            if opcode == Opcode.FOOTER:
                footer_at = at
                break
            if opcode not in SUMMARY_OPCODES:
                self.problems.append(f"summary: unexpected record (opcode 0x{opcode:02x}) at byte {at}")
                return None
            cls: Any = {
                Opcode.SCHEMA: Schema,
                Opcode.CHANNEL: Channel,
                Opcode.CHUNK_INDEX: ChunkIndex,
                Opcode.ATTACHMENT_INDEX: AttachmentIndex,
                Opcode.METADATA_INDEX: MetadataIndex,
                Opcode.STATISTICS: Statistics,
                Opcode.SUMMARY_OFFSET: SummaryOffset,
            }[Opcode(opcode)]
            try:
                records.append((at, opcode, _parse(cls, self.buf[body:end])))
            except ValueError as exc:
                self.problems.append(f"summary record at byte {at}: {exc}")
                return None
            at = end
        footer_end = footer_at + FOOTER_SIZE
        if footer_end > self.size or RECORD_HEAD.unpack_from(self.buf, footer_at)[1] != FOOTER_SIZE - 9:
            self.problems.append(f"footer at byte {footer_at} is damaged or truncated")
            return None
        footer = _parse(Footer, self.buf[footer_at + RECORD_HEAD.size : footer_end])
        if self.buf[footer_end : footer_end + len(MCAP_MAGIC)] != MCAP_MAGIC:
            self.problems.append(f"no closing MCAP magic after the footer at byte {footer_at} (truncated or damaged)")
            return None
        self._trailing(footer_end + len(MCAP_MAGIC))
        summary_start = start if records else 0
        if footer.summary_start != summary_start:
            self.problems.append(f"footer: summary_start {footer.summary_start} is not the summary's {summary_start}")
        if footer.summary_crc and _crc32(self.buf, start, footer_end - 4) != footer.summary_crc:
            self.problems.append(f"summary (bytes {start}-{footer_at}) fails the footer's CRC: it is damaged")
            return None
        return (*self._check_summary(records, footer), footer_end + len(MCAP_MAGIC))

    def _trailing(self, at: int) -> None:
        if at >= self.size:
            return
        extra = self.size - at
        if self.buf[at : at + len(MCAP_MAGIC)] == MCAP_MAGIC:
            self.problems.append(f"a second MCAP file is concatenated at byte {at} ({extra} bytes after the end)")
        else:
            self.problems.append(f"{extra} bytes of garbage after the end of the file (byte {at})")

    def _check_summary(self, records: list[tuple[int, int, Any]], footer: Footer):
        """Compare each summary record with the data section; a mismatch is a problem."""
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        statistics = None
        chunk_indexes: list[ChunkIndex] = []
        attachment_indexes: list[AttachmentIndex] = []
        metadata_indexes: list[MetadataIndex] = []
        offsets: list[tuple[int, SummaryOffset]] = []
        for at, opcode, r in records:
            if opcode == Opcode.SCHEMA:
                schemas[r.id] = r
            elif opcode == Opcode.CHANNEL:
                channels[r.id] = r
            elif opcode == Opcode.STATISTICS:
                statistics = r
            elif opcode == Opcode.CHUNK_INDEX:
                chunk_indexes.append(r)
            elif opcode == Opcode.ATTACHMENT_INDEX:
                attachment_indexes.append(r)
            elif opcode == Opcode.METADATA_INDEX:
                metadata_indexes.append(r)
            elif opcode == Opcode.SUMMARY_OFFSET:
                offsets.append((at, r))
        for kind, summary, data in (("Schema", schemas, self.schemas), ("Channel", channels, self.channels)):
            for rid, record in summary.items():
                if rid in data and data[rid] != record:
                    self.problems.append(f"summary: {kind} {rid} differs from the data section's")
        self._check_chunk_indexes(chunk_indexes)
        found_att = {at: (length, a) for at, (length, a) in self.attachment_at.items()}
        if len(attachment_indexes) != len(found_att):
            self.problems.append(
                f"summary: {len(attachment_indexes)} attachment indexes for {len(found_att)} attachments"
            )
        for ai in attachment_indexes:
            hit = found_att.get(ai.offset)
            if hit is None or (
                hit[0],
                hit[1].name,
                hit[1].media_type,
                len(hit[1].data),
                hit[1].log_time,
                hit[1].create_time,
            ) != (ai.length, ai.name, ai.media_type, ai.data_size, ai.log_time, ai.create_time):
                self.problems.append(f"summary: attachment index {ai.name!r} does not match the data section")
        if len(metadata_indexes) != len(self.metadata_at):
            self.problems.append(
                f"summary: {len(metadata_indexes)} metadata indexes for {len(self.metadata_at)} metadata records"
            )
        for mi in metadata_indexes:
            meta = self.metadata_at.get(mi.offset)
            if meta is None or (meta[0], meta[1]) != (mi.length, mi.name):
                self.problems.append(f"summary: metadata index {mi.name!r} does not match the data section")
        if statistics is not None:
            self._check_statistics(statistics, schemas, channels)
        if offsets:
            self._check_offsets(records, offsets, footer)
        return statistics, schemas, channels

    def _check_chunk_indexes(self, indexes: list[ChunkIndex]) -> None:
        if not indexes:
            return
        if len(indexes) != len(self.chunks):
            self.problems.append(f"summary: {len(indexes)} chunk indexes for {len(self.chunks)} chunks")
            return
        for ci, ref in zip(indexes, self.chunks, strict=True):
            found = {c: at for c, (at, _) in ref.index.items()}
            index_length = sum(length for _, length in ref.index.values())
            if (
                ci.chunk_start_offset,
                ci.chunk_length,
                ci.message_start_time,
                ci.message_end_time,
                ci.compression,
                ci.compressed_size,
                ci.uncompressed_size,
                dict(ci.message_index_offsets),
                ci.message_index_length,
            ) != (
                ref.offset,
                ref.length,
                ref.start_ns,
                ref.end_ns,
                ref.compression,
                ref.data_size,
                ref.uncompressed_size,
                found,
                index_length,
            ):
                self.problems.append(
                    f"summary: the chunk index for byte {ci.chunk_start_offset} does not match the "
                    f"chunk at byte {ref.offset}"
                )
                return

    def _check_statistics(self, s: Statistics, schemas: dict, channels: dict) -> None:
        counts: dict[int, int] = defaultdict(int)
        indexed = all(ref.index for ref in self.chunks)
        for ref in self.chunks:
            for c in ref.index:
                counts[c] += ref.index_count(c)
        wrong = []
        if s.chunk_count != len(self.chunks):
            wrong.append(f"chunk_count {s.chunk_count} (file: {len(self.chunks)})")
        if s.attachment_count != len(self.attachment_at):
            wrong.append(f"attachment_count {s.attachment_count} (file: {len(self.attachment_at)})")
        if s.metadata_count != len(self.metadata_at):
            wrong.append(f"metadata_count {s.metadata_count} (file: {len(self.metadata_at)})")
        if indexed:
            total = sum(counts.values())
            if s.message_count != total:
                wrong.append(f"message_count {s.message_count} (file: {total})")
            stated = {c: n for c, n in s.channel_message_counts.items() if n}
            if stated and stated != {c: n for c, n in counts.items() if n}:
                wrong.append("channel_message_counts")
        if self.chunks and total_range(self.chunks) != (s.message_start_time, s.message_end_time):
            wrong.append("message_start_time/message_end_time")
        if wrong:
            self.problems.append(f"summary: Statistics do not match the data section: {', '.join(wrong)}")

    def _check_offsets(self, records, offsets: list[tuple[int, SummaryOffset]], footer: Footer) -> None:
        if offsets[0][0] != footer.summary_offset_start:
            self.problems.append("footer: summary_offset_start does not point at the summary offsets")
        spans: dict[int, list[int]] = defaultdict(list)
        for at, opcode, _ in records:
            if opcode != Opcode.SUMMARY_OFFSET:
                spans[opcode].append(at)
        for _, so in offsets:
            starts = spans.get(so.group_opcode, [])
            if (starts[0] if starts else so.group_start) != so.group_start or bool(starts) != bool(so.group_length):
                self.problems.append(f"summary: the offset of group 0x{so.group_opcode:02x} is wrong")


def _crc32(buf: Any, start: int, stop: int) -> int:
    """CRC32 of buf[start:stop] in 16 MB pieces of a memoryview (no copy of the whole range),
    each piece's pages of the memory map released once read."""
    view = memoryview(buf)
    try:
        crc = 0
        for at in range(start, stop, 1 << 24):
            crc = zlib.crc32(view[at : min(at + (1 << 24), stop)], crc)
            _release(buf, at, min(at + (1 << 24), stop))
        return crc
    finally:
        view.release()


def _release(buf: Any, start: int, stop: int) -> None:
    """Drop the whole pages inside buf[start:stop] from this process's resident memory (a
    read-only file mapping: the kernel reads them again from its page cache if touched), so that
    walking a large file does not count it all as this process's memory. No-op for other buffers."""
    if not isinstance(buf, mmap.mmap) or not hasattr(mmap, "MADV_DONTNEED"):
        return
    first = -(-start // mmap.PAGESIZE) * mmap.PAGESIZE
    last = stop // mmap.PAGESIZE * mmap.PAGESIZE
    if last > first:
        buf.madvise(mmap.MADV_DONTNEED, first, last - first)


def total_range(chunks: list[ChunkRef]) -> tuple[int, int]:
    return min(r.start_ns for r in chunks), max(r.end_ns for r in chunks)


# ------------------------------------------------------------------------------------------------
# Whole-file reads


@dataclasses.dataclass
class McapContents:
    """Every message of an MCAP file, by channel, and its records.

    Attributes:
      path: the file.
      schemas, channels: by id (``mcap.records`` objects).
      messages: ChannelData by channel id.
      metadata: name -> entries.
      attachments: name -> Attachment record.
      complete: the file is whole and every check passed.
      problems: what is wrong with it, in words (empty when complete).
      unverified: content no CRC covers.
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
    unverified: list[Unverified] = dataclasses.field(default_factory=list)

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
        t0 = min((int(m.log_time_ns[0]) for m in self.messages.values() if len(m)), default=0)
        t_end = max((int(m.log_time_ns[-1]) for m in self.messages.values() if len(m)), default=0)
        return (
            f"{self.message_count} messages in {self.chunks} chunks intact, {(t_end - t0) / 1e9:.3f} s of log "
            f"time ({self.bytes_read} of {self.file_size} bytes)"
        )


class _Accumulator:
    def __init__(self, payloads: bool = True) -> None:
        self.blocks: dict[int, list[ChannelData]] = defaultdict(list)
        self.payloads = payloads

    def add(self, channels: dict[int, ChannelData]) -> None:
        for c, d in channels.items():
            if not self.payloads:  # times only (inspect): no payload bytes kept
                payloads: NDArray[np.uint8] | list[bytes] = np.zeros((len(d), 0), np.uint8)
            elif isinstance(d.payloads, np.ndarray):
                payloads = d.payloads  # a gathered copy already: no view of the chunk
            else:
                payloads = d.payloads
            self.blocks[c].append(ChannelData(d.log_time_ns, d.publish_time_ns, payloads))

    def result(self) -> dict[int, ChannelData]:
        out = {}
        for channel, blocks in self.blocks.items():
            log = np.concatenate([b.log_time_ns for b in blocks]).astype(np.int64)
            pub = np.concatenate([b.publish_time_ns for b in blocks]).astype(np.int64)
            widths = {b.payloads.shape[1] if isinstance(b.payloads, np.ndarray) else -1 for b in blocks}
            payloads: NDArray[np.uint8] | list[bytes]
            if len(widths) == 1 and -1 not in widths:
                payloads = np.concatenate([np.asarray(b.payloads) for b in blocks])
            else:
                payloads = [bytes(p) for b in blocks for p in b.payloads]
            order = np.argsort(log, kind="stable")
            if np.any(order != np.arange(len(order))):
                log, pub = log[order], pub[order]
                payloads = payloads[order] if isinstance(payloads, np.ndarray) else [payloads[i] for i in order]
            out[channel] = ChannelData(log, pub, payloads)
        return out


def read_mcap(
    path: str | Path,
    *,
    strict: bool = False,
    topics: Collection[str] | None = None,
    progress: Callable[[int], None] | None = None,
    verified_only: bool = False,
    payloads: bool = True,
) -> McapContents:
    """Read and verify every record of an MCAP file; messages into arrays per channel.

    Args:
      path: the file.
      strict: raise RecordingError on any problem (naming the region and how much is readable)
        instead of returning what could be read.
      topics: read only the messages of these topics; chunks whose index names only other
        channels are skipped without being inflated (the data-section CRC still covers them).
      progress: called with the number of bytes passed.
      verified_only: leave out the messages of chunks without a CRC.
      payloads: keep the message bytes (False: times only, (n, 0) payloads; for summaries).

    Raises:
      RecordingError: missing, special or non-MCAP file, or (strict) any problem.
    """
    mcap = scan_mcap(path)
    try:
        wanted = None if topics is None else mcap.channel_ids(topics)
        acc = _Accumulator(payloads)
        for chunk in mcap.chunks(channels=wanted, progress=progress, verified_only=verified_only):
            acc.add(chunk.channels)
        messages = acc.result()
        if topics is not None:
            messages = {c: d for c, d in messages.items() if c in mcap.channels and mcap.channels[c].topic in topics}
        contents = McapContents(
            path=Path(path),
            schemas=mcap.schemas,
            channels=mcap.channels,
            messages=messages,
            metadata=mcap.metadata,
            attachments=mcap.attachments,
            complete=mcap.complete and not mcap.problems,
            problems=mcap.problems,
            bytes_read=mcap.bytes_read,
            file_size=mcap.file_size,
            chunks=mcap.chunks_read,
            unverified=mcap.unverified,
        )
        if strict and mcap.problems:
            raise RecordingError(mcap.error_text(contents.summary_line()))
        return contents
    finally:
        mcap.close()
