"""A streaming MCAP writer for bulk messages: numpy builds whole chunks, channels interleaved in
log-time order.

The file is a standard MCAP (https://mcap.dev/spec): magic, header, metadata and attachments as
they are added, then compressed chunks, each followed by one message index per channel it holds,
then DataEnd (the CRC of the whole data section), the summary (schemas, channels, statistics,
chunk, attachment and metadata indexes, summary offsets, with its own CRC in the footer) and the
footer.

- **Log-time order across channels.** Messages are buffered and written sorted by (log time,
  channel), so every chunk interleaves channels and a streaming reader never sees log time go
  backwards. The caller promises an order in one of two ways: it calls ``flush()`` at points
  before which every message has been given (``record`` flushes after each simulated block), or
  it sets ``reorder_window_ns`` (live acquisition): a message is written once a message
  ``reorder_window_ns`` later has arrived. A message older than one already written is refused.
- **Self-contained chunks.** Each chunk carries the Schema and Channel records of the messages it
  holds, so a damaged chunk never orphans the messages of another (``recover`` keeps every intact
  chunk).
- **Crash safety.** Each chunk is written and flushed to the OS as a whole; with
  ``reorder_window_ns`` set, a chunk is written at least every ``flush_interval_s`` of log time
  and of wall time, so a killed live writer loses at most that much. Metadata records carry a
  CRC32 of their own entries (key ``pendsim.crc32``): MCAP covers metadata only by the
  data-section CRC, which a file cut off by a crash never got.
- **Errors.** Any OSError (full disk, permissions, ...) becomes ``OutputError`` naming the file.

Messages of one ``write_messages`` call share one size; sizes may differ between calls.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import time
import zlib
from collections import defaultdict
from pathlib import Path
from types import TracebackType

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.units import nanoseconds

from ...errors import OutputError
from ..outputs import output_error
from .records import (
    CHUNK_HEAD,
    COMPRESSIONS,
    MCAP_MAGIC,
    MESSAGE_PREFIX,
    MESSAGE_PREFIX_SIZE,
    RECORD_HEAD,
    compressor,
    message_index_record,
)

METADATA_CRC_KEY = "pendsim.crc32"


def metadata_crc(entries: dict[str, str]) -> int:
    """CRC32 of a metadata map's entries (all but ``METADATA_CRC_KEY``), in a canonical form."""
    items = sorted((k, v) for k, v in entries.items() if k != METADATA_CRC_KEY)
    return zlib.crc32(json.dumps(items, ensure_ascii=False).encode())


def _record_bytes(record: McapRecord) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())


class _Pending:
    """Messages of one write_messages call not yet written."""

    __slots__ = ("channel", "log", "payloads", "pub", "sequence")

    def __init__(
        self, channel: int, log: NDArray[np.int64], pub: NDArray[np.int64], payloads: NDArray[np.uint8], seq: NDArray
    ) -> None:
        self.channel, self.log, self.pub, self.payloads, self.sequence = channel, log, pub, payloads, seq

    def take(self, keep: NDArray[np.bool_]) -> None:
        self.log, self.pub, self.payloads, self.sequence = (
            self.log[keep],
            self.pub[keep],
            self.payloads[keep],
            self.sequence[keep],
        )


class BulkMcapWriter:
    """Write an MCAP file whose messages arrive as numpy arrays, in any channel order.

    Usage::

        with BulkMcapWriter(path, compression="zstd") as w:
            sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", text)
            cid = w.register_channel("/imu/m1", sid, "cdr")
            w.write_messages(cid, log_time_ns, payloads)  # (n,) int64, (n, size) uint8
            w.flush()  # every message up to here is given: write it out now

    Args:
      path: output file (created or truncated).
      compression: "zstd", "lz4" or "none".
      chunk_messages: at most this many messages per chunk.
      chunk_bytes: at most about this many uncompressed bytes of messages per chunk.
      reorder_window_ns: None (default): messages are written at ``flush()`` and ``finish()``
        only. A number: a message is written automatically once one this much later (log time)
        has been given; messages must then arrive at most this late.
      flush_interval_s: with ``reorder_window_ns``, write a chunk at least every this many
        seconds of log time and of wall time (the most a killed writer loses). None: by size only.
      profile: MCAP profile ("ros2").
      library: writer name recorded in the header.
      clock: wall clock for ``flush_interval_s``, s.

    Raises:
      OutputError: the file cannot be created or written (full disk, permissions, ...).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        compression: str = "zstd",
        chunk_messages: int = 16384,
        chunk_bytes: int = 2 << 20,
        reorder_window_ns: int | None = None,
        flush_interval_s: float | None = 1.0,
        profile: str = "ros2",
        library: str = "pendsim",
        clock=time.monotonic,
    ) -> None:
        self.compression, self._compress = compressor(compression)
        if chunk_messages < 1 or chunk_bytes < 1:
            raise ValueError(f"chunk_messages and chunk_bytes must be >= 1, got {chunk_messages}, {chunk_bytes}")
        if reorder_window_ns is not None and reorder_window_ns < 0:
            raise ValueError(f"reorder_window_ns must be >= 0 or None, got {reorder_window_ns}")
        if flush_interval_s is not None and not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0 or None, got {flush_interval_s}")
        self.chunk_messages = chunk_messages
        self.chunk_bytes = chunk_bytes
        self.reorder_window_ns = reorder_window_ns
        self.flush_interval_s = flush_interval_s
        self.path = Path(path)
        self._clock = clock
        self._crc = 0
        self._offset = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = defaultdict(int)
        self._pending: list[_Pending] = []
        self._pending_bytes = 0
        self._latest_ns = -1  # latest log time given
        self._written_ns = -1  # latest log time written to a chunk
        self._start_time: int | None = None
        self._end_time = 0
        self._last_flush_wall = clock()
        self._finished = False
        self._broken = False
        try:
            self._file = open(self.path, "wb")  # noqa: SIM115 - closed in finish()
        except OSError as exc:
            raise output_error(self.path, exc) from None
        self._write(MCAP_MAGIC + _record_bytes(Header(profile=profile, library=library)))
        self._os_flush()

    # -- low level --------------------------------------------------------------------------
    def _write(self, data: bytes | memoryview) -> None:
        try:
            self._file.write(data)
        except OSError as exc:
            self._fail(exc)
        self._crc = zlib.crc32(data, self._crc)
        self._offset += len(data)

    def _os_flush(self) -> None:
        try:
            self._file.flush()
        except OSError as exc:
            self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        self._broken = True
        with contextlib.suppress(OSError):  # the data are lost either way; report the first error
            self._file.close()
        raise output_error(self.path, exc) from None

    # -- public API ---------------------------------------------------------------------------
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register a schema and return its id (written in the chunks that use it)."""
        schema_id = len(self._schemas) + 1
        self._schemas[schema_id] = Schema(id=schema_id, name=name, encoding=encoding, data=bytes(data))
        return schema_id

    def register_channel(
        self, topic: str, schema_id: int, message_encoding: str, metadata: dict[str, str] | None = None
    ) -> int:
        """Register a channel and return its id (written in the chunks that use it)."""
        if schema_id not in self._schemas:
            raise ValueError(f"unknown schema id {schema_id}")
        channel_id = len(self._channels) + 1
        self._channels[channel_id] = Channel(
            id=channel_id, topic=topic, message_encoding=message_encoding, metadata=metadata or {}, schema_id=schema_id
        )
        return channel_id

    def write_messages(
        self,
        channel_id: int,
        log_time_ns: ArrayLike,
        payloads: ArrayLike,
        publish_time_ns: ArrayLike | None = None,
    ) -> None:
        """Give n messages of one channel (buffered; written in log-time order with the others).

        Args:
          channel_id: from register_channel.
          log_time_ns: (n,) integer nanoseconds, >= 0, non-decreasing, not before a message
            already written.
          payloads: (n, size) uint8 (all messages of this call the same size).
          publish_time_ns: (n,) or None (= log time).
        """
        if channel_id not in self._channels:
            raise ValueError(f"unknown channel id {channel_id}")
        log = np.asarray(log_time_ns, dtype=np.int64).reshape(-1)
        data = np.ascontiguousarray(payloads, dtype=np.uint8)
        if data.ndim != 2 or len(data) != len(log):
            raise ValueError(f"payloads must be (n, size) for n = {len(log)} log times, got {data.shape}")
        if not len(log):
            return
        if log[0] < 0 or np.any(np.diff(log) < 0):
            raise ValueError("log_time_ns must be non-negative and non-decreasing")
        if log[0] < self._written_ns:
            raise ValueError(
                f"a message at {int(log[0])} ns comes after messages up to {self._written_ns} ns were written; "
                "flush() only when every earlier message is given, or widen reorder_window_ns"
            )
        pub = log if publish_time_ns is None else np.asarray(publish_time_ns, dtype=np.int64).reshape(-1)
        if len(pub) != len(log):
            raise ValueError(f"publish_time_ns must have {len(log)} values, got {len(pub)}")
        first = self._counts[channel_id]
        sequence = (np.arange(first, first + len(log), dtype=np.int64) % (1 << 32)).astype(np.uint32)
        self._counts[channel_id] += len(log)
        self._pending.append(_Pending(channel_id, log, pub, data, sequence))
        self._pending_bytes += data.size + MESSAGE_PREFIX_SIZE * len(log)
        self._latest_ns = max(self._latest_ns, int(log[-1]))
        if self.reorder_window_ns is not None:
            self.advance(self._latest_ns)

    def advance(self, now_ns: int) -> None:
        """Declare the log time now reached (live writers call it also when no message comes):
        messages older than ``now_ns - reorder_window_ns`` are written when a chunk is due (by
        size, or ``flush_interval_s`` of log or wall time since the last one)."""
        if self.reorder_window_ns is None:
            return
        settled = int(now_ns) - self.reorder_window_ns
        due = self._pending_bytes >= self.chunk_bytes
        if self.flush_interval_s is not None:
            due = due or settled - max(self._written_ns, 0) >= nanoseconds(self.flush_interval_s)
            due = due or self._clock() - self._last_flush_wall >= self.flush_interval_s
        if due and settled >= 0:
            self._emit(settled)

    def flush(self, until_ns: int | None = None) -> None:
        """Write the buffered messages now (in chunks, each flushed to the OS): all of them, or
        those with log time <= ``until_ns`` (the caller will give none earlier than that)."""
        self._emit(until_ns)
        self._os_flush()

    def _emit(self, until_ns: int | None) -> None:
        """Write the buffered messages with log time <= until_ns (all for None), sorted."""
        self._last_flush_wall = self._clock()
        if not self._pending:
            return
        parts = []
        for k, p in enumerate(self._pending):
            rows = np.arange(len(p.log)) if until_ns is None else np.flatnonzero(p.log <= until_ns)
            parts.append((np.full(len(rows), k), rows, p.log[rows], np.full(len(rows), p.channel)))
        src = np.concatenate([q[0] for q in parts])
        if not len(src):
            return
        row = np.concatenate([q[1] for q in parts])
        log = np.concatenate([q[2] for q in parts])
        channel = np.concatenate([q[3] for q in parts])
        order = np.lexsort((row, src, channel, log))  # log time, then channel, then arrival
        src, row, log = src[order], row[order], log[order]
        size = np.array([p.payloads.shape[1] + MESSAGE_PREFIX_SIZE for p in self._pending])[src]
        # Cut into chunks of at most chunk_messages messages and about chunk_bytes bytes.
        ends = np.cumsum(size)
        cuts = [0]
        while cuts[-1] < len(src):
            lo = cuts[-1]
            by_bytes = int(np.searchsorted(ends, ends[lo] - size[lo] + self.chunk_bytes, side="right"))
            cuts.append(min(max(by_bytes, lo + 1), lo + self.chunk_messages, len(src)))
        for lo, hi in itertools.pairwise(cuts):
            self._write_chunk(src[lo:hi], row[lo:hi], log[lo:hi], size[lo:hi])
        # Drop what was written from the buffer.
        kept: list[_Pending] = []
        for p in self._pending:
            if until_ns is not None:
                p.take(p.log > until_ns)
                if len(p.log):
                    kept.append(p)
        self._pending = kept
        self._pending_bytes = sum(p.payloads.size + MESSAGE_PREFIX_SIZE * len(p.log) for p in kept)
        self._os_flush()

    def _write_chunk(
        self, src: NDArray[np.int64], row: NDArray[np.int64], log: NDArray[np.int64], size: NDArray[np.int64]
    ) -> None:
        n = len(src)
        # Every message as one row of a (n, widest) table, then the rows cut to their own sizes.
        widest = int(size.max())
        table = np.zeros((n, widest), dtype=np.uint8)
        channels = np.empty(n, dtype=np.int64)
        for k in np.unique(src):
            p = self._pending[k]
            at = np.flatnonzero(src == k)
            rows = row[at]
            prefix = np.empty(len(at), dtype=MESSAGE_PREFIX)
            prefix["opcode"] = Opcode.MESSAGE
            prefix["length"] = p.payloads.shape[1] + MESSAGE_PREFIX_SIZE - RECORD_HEAD.size
            prefix["channel"] = p.channel
            prefix["sequence"] = p.sequence[rows]
            prefix["log_time"] = p.log[rows]
            prefix["publish_time"] = p.pub[rows]
            width = p.payloads.shape[1] + MESSAGE_PREFIX_SIZE
            table[at, :MESSAGE_PREFIX_SIZE] = prefix.view(np.uint8).reshape(len(at), MESSAGE_PREFIX_SIZE)
            table[at, MESSAGE_PREFIX_SIZE:width] = p.payloads[rows]
            channels[at] = p.channel
        messages = table if np.all(size == widest) else table[np.arange(widest) < size[:, None]]
        # The chunk opens with the Schema and Channel records its messages use.
        used = sorted({int(c) for c in np.unique(channels)})
        head = b"".join(
            _record_bytes(self._schemas[s]) for s in sorted({self._channels[c].schema_id for c in used})
        ) + b"".join(_record_bytes(self._channels[c]) for c in used)
        raw = head + messages.tobytes()
        data = self._compress(raw) if self._compress else raw
        start_time, end_time = int(log[0]), int(log[-1])
        compression = self.compression.encode()
        body_head = (
            CHUNK_HEAD.pack(start_time, end_time, len(raw), zlib.crc32(raw))
            + np.uint32(len(compression)).tobytes()
            + compression
            + np.uint64(len(data)).tobytes()
        )
        chunk_offset = self._offset
        chunk_length = RECORD_HEAD.size + len(body_head) + len(data)
        self._write(RECORD_HEAD.pack(Opcode.CHUNK, len(body_head) + len(data)) + body_head)
        self._write(data)
        offsets = len(head) + np.concatenate([[0], np.cumsum(size[:-1])])
        index_offsets = {}
        index_start = self._offset
        for c in used:
            at = channels == c
            index_offsets[c] = self._offset
            self._write(message_index_record(c, log[at], offsets[at]))
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start_time,
                message_end_time=end_time,
                chunk_start_offset=chunk_offset,
                chunk_length=chunk_length,
                message_index_offsets=index_offsets,
                message_index_length=self._offset - index_start,
                compression=self.compression,
                compressed_size=len(data),
                uncompressed_size=len(raw),
            )
        )
        self._start_time = start_time if self._start_time is None else min(self._start_time, start_time)
        self._end_time = max(self._end_time, end_time)
        self._written_ns = max(self._written_ns, end_time)
        self._os_flush()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a Metadata record now (string keys and values; a CRC32 entry is added)."""
        entries = {str(k): str(v) for k, v in data.items() if k != METADATA_CRC_KEY}
        entries[METADATA_CRC_KEY] = f"{metadata_crc(entries):08x}"
        offset = self._offset
        record = _record_bytes(Metadata(name=name, metadata=entries))
        self._write(record)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(record), name=name))
        self._os_flush()

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time_ns: int = 0) -> None:
        """Write an Attachment record now (e.g. the MJCF the run used)."""
        offset = self._offset
        attachment = Attachment(
            create_time=log_time_ns, log_time=log_time_ns, name=name, media_type=media_type, data=bytes(data)
        )
        record = _record_bytes(attachment)
        self._write(record)
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=offset,
                length=len(record),
                create_time=log_time_ns,
                log_time=log_time_ns,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )
        self._os_flush()

    @property
    def written_until_ns(self) -> int:
        """Log time up to which messages are written (-1: none): a message older than this is
        refused, so a live writer drops packets that arrive later than its reorder window."""
        return self._written_ns

    @property
    def message_count(self) -> int:
        """Messages given so far (written or buffered)."""
        return sum(self._counts.values())

    def finish(self) -> None:
        """Write what is buffered, the summary and the footer, and close the file. Idempotent."""
        if self._finished:
            return
        self._finished = True
        try:
            if self._broken:
                return
            self._emit(None)
            self._write_summary()
        finally:
            if not self._file.closed:
                try:
                    self._file.close()
                except OSError as exc:
                    self._fail(exc)

    def _write_summary(self) -> None:
        self._write(_record_bytes(DataEnd(data_section_crc=self._crc)))
        summary_start = self._offset
        builder = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records) -> None:
            start = builder.count
            for r in records:
                r.write(builder)
            if builder.count > start:
                offsets.append(
                    SummaryOffset(
                        group_opcode=opcode, group_start=summary_start + start, group_length=builder.count - start
                    )
                )

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(
            Opcode.STATISTICS,
            [
                Statistics(
                    message_count=sum(self._counts.values()),
                    schema_count=len(self._schemas),
                    channel_count=len(self._channels),
                    attachment_count=len(self._attachment_indexes),
                    metadata_count=len(self._metadata_indexes),
                    chunk_count=len(self._chunk_indexes),
                    message_start_time=self._start_time or 0,
                    message_end_time=self._end_time,
                    channel_message_counts={c: n for c, n in self._counts.items() if n},
                )
            ],
        )
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + builder.count
        for o in offsets:
            o.write(builder)
        summary = bytes(builder.end())
        footer = _record_bytes(
            Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=0)
        )
        crc = zlib.crc32(footer[:-4], zlib.crc32(summary))
        footer = footer[:-4] + np.uint32(crc).tobytes()
        try:
            self._file.write(summary + footer + MCAP_MAGIC)
            self._file.flush()
        except OSError as exc:
            self._fail(exc)

    def close_unfinished(self) -> None:
        """Close the file without a summary (what a killed writer leaves; for tests and aborts)."""
        self._finished = True
        self._file.close()

    def __enter__(self) -> BulkMcapWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        # Even after an error, close the file as a valid MCAP holding everything given so far
        # (unless writing itself failed: then just close it).
        if isinstance(exc, OutputError):
            self._broken = True
        self.finish()


__all__ = ["COMPRESSIONS", "MCAP_MAGIC", "METADATA_CRC_KEY", "BulkMcapWriter", "metadata_crc"]
