"""Pass 1 over an MCAP file: its structure and every CRC but the chunks'.

``Scanner`` walks the records from the start (no summary needed, so a file cut off by a crash is
read up to its last complete record). Checked: every record's framing, each attachment's CRC,
the data-section CRC in DataEnd, the summary CRC in the footer, the closing magic, and that the
summary (schemas, channels, statistics, chunk, attachment and metadata indexes, summary
offsets) matches the data section's own records; a summary copy never overrides the original.
Bytes after the closing magic (garbage, a second MCAP file) are reported. After a damaged
record the walk resynchronises on the next intact chunk (``resync``). Chunks are located, not
inflated (``McapFile.chunks`` does that).
"""

from __future__ import annotations

import dataclasses
import zlib
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
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

from .chunks import ChunkRef, read_chunk_ref, total_range
from .mapping import crc32_range
from .records import (
    FOOTER_SIZE,
    INDEX_ENTRY,
    MCAP_MAGIC,
    RECORD_HEAD,
    SUMMARY_OPCODES,
    parse_record,
    record_frame,
)
from .resync import next_intact_chunk
from .writer import METADATA_CRC_KEY, metadata_crc

UNCHUNKED = "a message outside chunks (pendsim reads chunked files only)"


@dataclasses.dataclass(frozen=True)
class Unverified:
    """Content of a file that no CRC covers (kind: metadata, attachment, schema, channel, chunk)."""

    kind: str
    name: str  # metadata/attachment name, schema/channel id, or the chunk's byte offset
    offset: int

    def __str__(self) -> str:
        return f"{self.kind} {self.name} at byte {self.offset} (no CRC covers it)"


class Scanner:
    """Pass 1's findings, as attributes, once ``run`` has walked the file.

    Attributes:
      path, buf, size: the file, its memory map and its size in bytes.
      problems: what is wrong, one phrase each naming the region and byte offset.
      unverified: content no CRC covers.
      schemas, channels: by id, the data section's records outside chunks.
      metadata: name -> entries (without the CRC entry pendsim adds).
      attachments: name -> Attachment record (CRC checked).
      chunks: every chunk found, in file order, with its message index.
      complete: DataEnd, summary and footer are there, and nothing was found wrong.
      bytes_read: the offset up to which the file was understood.
      statistics, summary_schemas, summary_channels: the summary's records (None, empty: none).
    """

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
        self.complete = False
        self.bytes_read = 0
        self.statistics: Statistics | None = None
        self.summary_schemas: dict[int, Schema] = {}
        self.summary_channels: dict[int, Channel] = {}

    def run(self) -> Scanner:
        """Walk the data section, then the summary and footer; returns this scanner."""
        offset = self._header()
        end = offset or len(MCAP_MAGIC)
        reached_end = False
        while offset is not None and not reached_end:
            offset, reached_end = self._data_record(offset)
            end = offset if offset is not None else end
        if reached_end and offset is not None:
            summary = self._summary(offset)
            if summary is not None:
                self.statistics, self.summary_schemas, self.summary_channels, end = summary
                self.complete = not self.problems
        self._note_unverified()
        self.bytes_read = min(end, self.size)
        return self

    # -- data section ---------------------------------------------------------------------------
    def _header(self) -> int | None:
        at = len(MCAP_MAGIC)
        head = self._frame(at)
        if head is None or head[0] != Opcode.HEADER:
            self.problems.append(f"no Header record at byte {at} (the file is damaged or truncated)")
            return self._resync(at) if self.recover else None
        try:
            parse_record(Header, self.buf[at + RECORD_HEAD.size : head[2]])
        except ValueError as exc:
            self.problems.append(f"Header at byte {at}: {exc}")
        return head[2]

    def _frame(self, at: int) -> tuple[int, int, int] | None:
        """(opcode, body start, end) of the record at ``at``, or None if it cannot fit."""
        return record_frame(self.buf, self.size, at)

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
                record = parse_record(Schema if opcode == Opcode.SCHEMA else Channel, self.buf[body:end])
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
        at = next_intact_chunk(self.buf, self.size, start)
        if at is not None:
            self.problems.append(
                f"resynchronised on an intact chunk at byte {at} (skipped {at - start + 1} damaged bytes)"
            )
        return at

    def _chunk(self, at: int, body: int, end: int) -> None:
        ref = read_chunk_ref(self.buf, at, body, end)
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
        record = parse_record(Metadata, self.buf[body:end])
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
        record = parse_record(Attachment, self.buf[body:end])
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
        if crc32_range(self.buf, 0, at) != crc:
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
                records.append((at, opcode, parse_record(cls, self.buf[body:end])))
            except ValueError as exc:
                self.problems.append(f"summary record at byte {at}: {exc}")
                return None
            at = end
        footer_end = footer_at + FOOTER_SIZE
        if footer_end > self.size or RECORD_HEAD.unpack_from(self.buf, footer_at)[1] != FOOTER_SIZE - 9:
            self.problems.append(f"footer at byte {footer_at} is damaged or truncated")
            return None
        footer = parse_record(Footer, self.buf[footer_at + RECORD_HEAD.size : footer_end])
        if self.buf[footer_end : footer_end + len(MCAP_MAGIC)] != MCAP_MAGIC:
            self.problems.append(f"no closing MCAP magic after the footer at byte {footer_at} (truncated or damaged)")
            return None
        self._trailing(footer_end + len(MCAP_MAGIC))
        summary_start = start if records else 0
        if footer.summary_start != summary_start:
            self.problems.append(f"footer: summary_start {footer.summary_start} is not the summary's {summary_start}")
        if footer.summary_crc and crc32_range(self.buf, start, footer_end - 4) != footer.summary_crc:
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
