"""Numpy extraction of a chunk's messages: from its inflated records to one ``ChannelData`` per
channel, the messages of one size as an (n, size) array.

``chunk_messages`` parses through the message index that follows the chunk (its offsets must
tile the chunk exactly), or record by record where there is no usable index;
``messages_compiled`` does the index check in one pass of numba's ``chunk_kernel`` and gives the
same messages, or None where the numpy path must name a problem.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Collection
from typing import Any

import numpy as np
from mcap.opcode import Opcode
from mcap.records import Channel, Schema
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from .chunks import ChunkRef
from .records import (
    INDEX_ENTRY,
    MESSAGE_FIELDS,
    MESSAGE_PREFIX,
    MESSAGE_PREFIX_SIZE,
    RECORD_HEAD,
    parse_record,
)


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


def read_index(buf: Any, ref: ChunkRef) -> dict[int, NDArray] | None:
    """The chunk's message index entries per channel (None if it has no index)."""
    if not ref.index:
        return None
    out = {}
    for channel, (offset, length) in ref.index.items():
        body = offset + RECORD_HEAD.size + 6
        out[channel] = np.frombuffer(buf, dtype=INDEX_ENTRY, count=(length - RECORD_HEAD.size - 6) // 16, offset=body)
    return out


def chunk_messages(
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


def messages_compiled(
    raw: bytes, buf: Any, ref: ChunkRef, compiled: CompiledIndex, channels: Collection[int] | None = None
) -> tuple[list, dict[int, ChannelData]] | None:
    """``_messages_by_index`` in one compiled pass (``chunk_kernel.index_messages``): the same
    records and messages, or None where the kernel does not accept the chunk (the caller then
    parses it with numpy, which names what is wrong)."""
    # numba, imported only when a walk asks for it: 0.3-0.5 s of start-up a process need not pay
    from .chunk_kernel import index_messages

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
        first = index_messages(data, index_bytes, spans, slot, row_of, offsets, log, publish, sizes, counts)
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
class CompiledIndex:
    """``messages_compiled``'s tables by channel id, (65536,) each, -1 between chunks (set and
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
        records.append(parse_record(Schema if opcode == Opcode.SCHEMA else Channel, raw[at + RECORD_HEAD.size : end]))
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
            records.append(
                parse_record(Schema if opcode == Opcode.SCHEMA else Channel, raw[at + RECORD_HEAD.size : end])
            )
        else:
            raise ValueError(f"unexpected record (opcode 0x{opcode:02x}) inside the chunk")
        at = end
    if not offsets:
        return records, {}
    where = np.array(offsets, dtype=np.int64)
    prefix = sliding_window_view(data, MESSAGE_PREFIX_SIZE)[where].copy().view(MESSAGE_PREFIX).reshape(-1)
    return records, _group(data, where, prefix, channels)
