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

This module is the reader's public face (``scan_mcap``, ``McapFile``, ``read_mcap``); the work
lies in ``scan`` (pass 1), ``resync`` (after damage), ``chunks`` (inflation), ``extract``
(messages into arrays) and ``mapping`` (the memory map).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections import defaultdict
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Attachment, Channel, Schema, Statistics
from numpy.typing import NDArray

from pendsim_mj.errors import RecordingError
from pendsim_mj.units import seconds

from .chunks import INFLATE_AHEAD, ChunkRef, inflate, inflate_ahead, total_range
from .extract import ChannelData, CompiledIndex, chunk_messages, read_index
from .extract import messages_compiled as _messages_compiled
from .mapping import open_map, release
from .records import MCAP_MAGIC, import_hint
from .scan import UNCHUNKED, Scanner, Unverified

__all__ = [
    "INFLATE_AHEAD",
    "UNCHUNKED",
    "ChannelData",
    "ChunkMessages",
    "ChunkRef",
    "McapContents",
    "McapFile",
    "Unverified",
    "open_map",
    "read_mcap",
    "scan_mcap",
    "total_range",
]


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
        fast = CompiledIndex(*np.full((2, 1 << 16), -1, np.int64)) if compiled else None
        # closed on every way out (a consumer that stops early included): no inflation is left
        # running on the map
        with contextlib.closing(inflate_ahead(buf, refs)) as inflated:
            for ref, raw in inflated:
                if progress is not None:
                    progress(ref.length)
                if isinstance(raw, Exception):
                    release(buf, ref.offset, ref.offset + ref.length)
                    self.problems.append(f"chunk at byte {ref.offset}: {raw}")
                    continue
                parsed = self._parse_chunk(ref, raw, wanted, fast)
                del raw
                # the chunk and its message index records (as large as the chunk's messages'
                # data for small messages) leave resident memory once parsed
                ends = (o + n for o, n in ref.index.values())
                release(buf, ref.offset, max([ref.offset + ref.length, *ends]))
                if parsed is not None:
                    self.chunks_read += 1
                    yield parsed

    def _parse_chunk(
        self, ref: ChunkRef, raw: bytes, channels: Collection[int] | None = None, fast: CompiledIndex | None = None
    ) -> ChunkMessages | None:
        try:  # _messages_compiled: looked up in this module (tests/io/test_chunk_kernel.py counts the calls)
            parsed = _messages_compiled(raw, self._buf, ref, fast, channels) if fast is not None and ref.index else None
            records, messages = parsed or chunk_messages(raw, read_index(self._buf, ref), channels)
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
        intact, n = [], 0
        for ref in self.chunk_refs:
            raw = inflate(self._buf, ref) if self._buf is not None else None
            if not isinstance(raw, Exception):
                intact.append(ref)
                n += _messages_in(ref, raw)
            if self._buf is not None:
                release(self._buf, ref.offset, ref.offset + ref.length)
        t0 = min((r.start_ns for r in intact), default=0)
        t_end = max((r.end_ns for r in intact), default=0)
        return (
            f"{n} messages in {len(intact)} chunk{'s' if len(intact) != 1 else ''} intact, "
            f"{seconds(t_end - t0):.3f} s of log time ({self.bytes_read} of {self.file_size} bytes)"
        )


def _messages_in(ref: ChunkRef, raw: bytes | None) -> int:
    """A chunk's messages as ``recover`` counts them: its records walked where they are at hand
    (a cut file's last chunk may have lost its message index, which then lists fewer), else as its
    index lists them."""
    if raw is None:
        return sum(ref.index_count(c) for c in ref.index)
    try:
        _, messages = chunk_messages(raw, None)
    except ValueError:
        return sum(ref.index_count(c) for c in ref.index)
    return sum(len(m) for m in messages.values())


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
    found = Scanner(path, buf, size, recover).run()
    mf = McapFile(
        path=path,
        file_size=size,
        schemas=found.schemas,
        channels=found.channels,
        metadata=found.metadata,
        attachments=found.attachments,
        chunk_refs=found.chunks,
        problems=found.problems,
        unverified=found.unverified,
        complete=found.complete,
        bytes_read=found.bytes_read,
        statistics=found.statistics,
        _buf=buf,
        _summary_channels=found.summary_channels,
        _summary_schemas=found.summary_schemas,
        _defined={("Schema", i) for i in found.schemas} | {("Channel", i) for i in found.channels},
    )
    for sid, s in found.summary_schemas.items():
        mf.schemas.setdefault(sid, s)
    for cid, c in found.summary_channels.items():
        mf.channels.setdefault(cid, c)
    return mf


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
            f"{self.message_count} messages in {self.chunks} chunk{'s' if self.chunks != 1 else ''} intact, "
            f"{seconds(t_end - t0):.3f} s of log time ({self.bytes_read} of {self.file_size} bytes)"
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
