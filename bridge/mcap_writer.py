"""An MCAP writer for bulk, fixed-size messages: numpy builds whole chunks at once.

The file is a standard MCAP (https://mcap.dev/spec): header, schemas and channels written and
flushed before any message, then compressed chunks, each holding messages of one channel and
followed by its message index, then the summary (schemas, channels, statistics, chunk,
attachment and metadata indexes, summary offsets) and the footer. The record framing reuses
``mcap.records``; only message records and message indexes are built with numpy.

Crash safety: every chunk is written and flushed as a whole, so a process killed at any moment
leaves a file whose every complete chunk can be read back (``mcap_reader`` recovers it).
"""

from __future__ import annotations

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
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MCAP_MAGIC = b"\x89MCAP0\r\n"
COMPRESSIONS = ("zstd", "lz4", "none")
_MESSAGE_PREFIX = np.dtype(
    [
        ("opcode", "u1"),
        ("length", "<u8"),
        ("channel", "<u2"),
        ("sequence", "<u4"),
        ("log_time", "<u8"),
        ("publish_time", "<u8"),
    ]
)
_INDEX_ENTRY = np.dtype([("timestamp", "<u8"), ("offset", "<u8")])


def _compressor(name: str):
    if name == "zstd":
        import zstandard

        ctx = zstandard.ZstdCompressor(level=3)
        return "zstd", ctx.compress
    if name == "lz4":
        import lz4.frame

        return "lz4", lz4.frame.compress
    if name == "none":
        return "", None
    raise ValueError(f"unknown compression {name!r}; allowed: {', '.join(COMPRESSIONS)}")


class BulkMcapWriter:
    """Write an MCAP file whose messages arrive as numpy arrays.

    Usage::

        with BulkMcapWriter(path, compression="zstd") as w:
            sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", text)
            cid = w.register_channel("/imu/m1", sid, "cdr")
            w.write_messages(cid, log_time_ns, payloads)  # (n,) int64, (n, size) uint8

    Args:
      path: output file (created or truncated).
      compression: "zstd", "lz4" or "none".
      chunk_messages: at most this many messages per chunk.
      profile: MCAP profile ("ros2").
      library: writer name recorded in the header.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        compression: str = "zstd",
        chunk_messages: int = 4096,
        profile: str = "ros2",
        library: str = "pendsim",
    ) -> None:
        self.compression, self._compress = _compressor(compression)
        if chunk_messages < 1:
            raise ValueError(f"chunk_messages must be >= 1, got {chunk_messages}")
        self.chunk_messages = chunk_messages
        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in finish()
        self._crc = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = defaultdict(int)
        self._start_time: int | None = None
        self._end_time = 0
        self._finished = False
        self._write(MCAP_MAGIC)
        self._write_record(Header(profile=profile, library=library))
        self._file.flush()

    # -- low level --------------------------------------------------------------------------
    def _write(self, data: bytes | memoryview) -> None:
        self._file.write(data)
        self._crc = zlib.crc32(data, self._crc)

    def _write_record(self, record) -> int:
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        self._write(data)
        return len(data)

    # -- public API ---------------------------------------------------------------------------
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a Schema record now (outside chunks) and return its id."""
        schema_id = len(self._schemas) + 1
        self._schemas[schema_id] = Schema(id=schema_id, name=name, encoding=encoding, data=data)
        self._write_record(self._schemas[schema_id])
        self._file.flush()
        return schema_id

    def register_channel(
        self, topic: str, schema_id: int, message_encoding: str, metadata: dict[str, str] | None = None
    ) -> int:
        """Write a Channel record now (outside chunks) and return its id."""
        if schema_id not in self._schemas:
            raise ValueError(f"unknown schema id {schema_id}")
        channel_id = len(self._channels) + 1
        channel = Channel(
            id=channel_id, topic=topic, message_encoding=message_encoding, metadata=metadata or {}, schema_id=schema_id
        )
        self._channels[channel_id] = channel
        self._write_record(channel)
        self._file.flush()
        return channel_id

    def write_messages(
        self, channel_id: int, log_time_ns: np.ndarray, payloads: np.ndarray, publish_time_ns: np.ndarray | None = None
    ) -> None:
        """Write n messages of one channel, as whole chunks, each flushed to the OS.

        Args:
          channel_id: from register_channel.
          log_time_ns: (n,) integer nanoseconds, non-decreasing.
          payloads: (n, size) uint8 (all messages the same size).
          publish_time_ns: (n,) or None (= log time).
        """
        if channel_id not in self._channels:
            raise ValueError(f"unknown channel id {channel_id}")
        log_time = np.asarray(log_time_ns, dtype=np.int64)
        payloads = np.ascontiguousarray(payloads, dtype=np.uint8)
        if payloads.ndim != 2 or len(payloads) != len(log_time):
            raise ValueError(f"payloads must be (n, size) for n = {len(log_time)} log times, got {payloads.shape}")
        if len(log_time) and (log_time.min() < 0 or np.any(np.diff(log_time) < 0)):
            raise ValueError("log_time_ns must be non-negative and non-decreasing")
        publish = log_time if publish_time_ns is None else np.asarray(publish_time_ns, dtype=np.int64)
        for start in range(0, len(log_time), self.chunk_messages):
            stop = min(start + self.chunk_messages, len(log_time))
            self._write_chunk(channel_id, log_time[start:stop], publish[start:stop], payloads[start:stop])

    def _write_chunk(self, channel_id: int, log_time: np.ndarray, publish: np.ndarray, payloads: np.ndarray) -> None:
        n, size = payloads.shape
        first_sequence = self._counts[channel_id]
        record_size = _MESSAGE_PREFIX.itemsize + size
        records = np.empty((n, record_size), dtype=np.uint8)
        prefix = records[:, : _MESSAGE_PREFIX.itemsize].view(_MESSAGE_PREFIX).reshape(n)
        prefix["opcode"] = Opcode.MESSAGE
        prefix["length"] = record_size - 9
        prefix["channel"] = channel_id
        prefix["sequence"] = np.arange(first_sequence, first_sequence + n, dtype=np.uint32)
        prefix["log_time"] = log_time
        prefix["publish_time"] = publish
        records[:, _MESSAGE_PREFIX.itemsize :] = payloads
        raw = records.tobytes()
        data = self._compress(raw) if self._compress else raw
        start_time, end_time = int(log_time[0]), int(log_time[-1])
        chunk = Chunk(
            compression=self.compression,
            data=data,
            message_start_time=start_time,
            message_end_time=end_time,
            uncompressed_crc=zlib.crc32(raw),
            uncompressed_size=len(raw),
        )
        chunk_offset = self._file.tell()
        chunk_length = self._write_record(chunk)
        # Message index: (log time, offset in the uncompressed chunk) per message.
        index_offset = self._file.tell()
        entries = np.empty(n, dtype=_INDEX_ENTRY)
        entries["timestamp"] = log_time
        entries["offset"] = np.arange(n, dtype=np.uint64) * record_size
        body = entries.tobytes()
        head = (
            np.array([Opcode.MESSAGE_INDEX], "u1").tobytes()
            + np.uint64(2 + 4 + len(body)).tobytes()
            + np.uint16(channel_id).tobytes()
            + np.uint32(len(body)).tobytes()
        )
        self._write(head + body)
        self._file.flush()
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start_time,
                message_end_time=end_time,
                chunk_start_offset=chunk_offset,
                chunk_length=chunk_length,
                message_index_offsets={channel_id: index_offset},
                message_index_length=len(head) + len(body),
                compression=self.compression,
                compressed_size=len(data),
                uncompressed_size=len(raw),
            )
        )
        self._counts[channel_id] += n
        self._start_time = start_time if self._start_time is None else min(self._start_time, start_time)
        self._end_time = max(self._end_time, end_time)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a Metadata record (string keys and values)."""
        offset = self._file.tell()
        length = self._write_record(Metadata(name=name, metadata={str(k): str(v) for k, v in data.items()}))
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self._file.flush()

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time_ns: int = 0) -> None:
        """Write an Attachment record (e.g. the MJCF the run used)."""
        offset = self._file.tell()
        record = Attachment(create_time=log_time_ns, log_time=log_time_ns, name=name, media_type=media_type, data=data)
        length = self._write_record(record)
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=offset,
                length=length,
                create_time=log_time_ns,
                log_time=log_time_ns,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )
        self._file.flush()

    def finish(self) -> None:
        """Write the summary and footer and close the file. Idempotent."""
        if self._finished:
            return
        self._finished = True
        self._write_record(DataEnd(data_section_crc=self._crc))
        summary_start = self._file.tell()
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
                    channel_message_counts=dict(self._counts),
                )
            ],
        )
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + builder.count
        for o in offsets:
            o.write(builder)
        summary = builder.end()
        crc = zlib.crc32(summary)
        footer_head = (
            np.array([Opcode.FOOTER], "u1").tobytes()
            + np.array([20, summary_start, summary_offset_start], "<u8").tobytes()
        )
        crc = zlib.crc32(footer_head, crc)
        self._file.write(summary)
        builder = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc).write(builder)
        self._file.write(builder.end())
        self._file.write(MCAP_MAGIC)
        self._file.close()

    def __enter__(self) -> BulkMcapWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        # Even after an error, close the file as a valid MCAP holding everything written so far.
        self.finish()


__all__ = ["COMPRESSIONS", "MCAP_MAGIC", "BulkMcapWriter"]
