"""Operations on whole MCAP files: rewriting what was read (all of it, or a selection) into a
new complete file, and recovering the readable part of a damaged one."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bridge.mcap_reader import ChannelData, McapContents, read_mcap
from bridge.mcap_writer import BulkMcapWriter


def rewrite(
    contents: McapContents,
    output: str | Path,
    *,
    rows: Callable[[int, ChannelData], np.ndarray | None] | None = None,
    shift_ns: int = 0,
    library: str = "pendsim",
    compression: str = "zstd",
) -> int:
    """Write ``contents`` to a new, complete and indexed MCAP file: metadata, attachments,
    schemas, channels, and the messages ``rows(channel_id, data)`` chooses (indices; None drops
    the channel; default all), log times moved back by ``shift_ns``. The file is written beside
    ``output`` and renamed into place only when complete. Returns the messages written."""
    output = Path(output)
    partial = output.with_name(f".{output.name}.partial")
    written = 0
    try:
        with BulkMcapWriter(partial, compression=compression, library=library) as w:
            for name, values in contents.metadata.items():
                w.add_metadata(name, values)
            for a in contents.attachments.values():
                w.add_attachment(a.name, a.media_type, a.data, a.log_time)
            schema_ids = {
                sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in sorted(contents.schemas.items())
            }
            for cid, ch in sorted(contents.channels.items()):
                data = contents.messages.get(cid)
                empty = ChannelData(np.zeros(0, np.int64), np.zeros(0, np.int64), [])
                chosen = rows(cid, data if data is not None else empty) if rows else None
                if rows is not None and chosen is None:
                    continue  # channel dropped
                schema = schema_ids.get(ch.schema_id) or _placeholder(w)
                new_id = w.register_channel(ch.topic, schema, ch.message_encoding, ch.metadata)
                if data is None or not len(data):
                    continue
                index = np.arange(len(data)) if chosen is None else np.asarray(chosen)
                written += _write_rows(w, new_id, data, index, shift_ns)
        partial.replace(output)
    finally:
        partial.unlink(missing_ok=True)
    return written


def _write_rows(w: BulkMcapWriter, channel_id: int, data: ChannelData, index: np.ndarray, shift_ns: int) -> int:
    if not len(index):
        return 0
    log, pub = data.log_time_ns[index] - shift_ns, data.publish_time_ns[index] - shift_ns
    if isinstance(data.payloads, np.ndarray):
        w.write_messages(channel_id, log, data.payloads[index], pub)
        return len(index)
    payloads = [data.payloads[i] for i in index]  # messages of varying size: runs of equal size
    sizes = np.array([len(p) for p in payloads])
    edges = np.flatnonzero(np.diff(sizes)) + 1
    for lo, hi in zip(np.r_[0, edges], np.r_[edges, len(sizes)], strict=True):
        block = np.frombuffer(b"".join(payloads[lo:hi]), np.uint8).reshape(hi - lo, sizes[lo])
        w.write_messages(channel_id, log[lo:hi], block, pub[lo:hi])
    return len(index)


def recover(broken: str | Path, fixed: str | Path, *, compression: str = "zstd") -> McapContents:
    """Rewrite everything readable in ``broken`` (schemas, channels, messages of every complete
    chunk, metadata, attachments) into a new, complete and indexed MCAP file ``fixed``.
    Returns what was read from ``broken``."""
    contents = read_mcap(broken, strict=False)
    rewrite(contents, fixed, library="pendsim recover", compression=compression)
    return contents


def _placeholder(w: BulkMcapWriter) -> int:
    """A schema for a channel whose schema record was lost (MCAP needs one to reference)."""
    return w.register_schema("unknown", "", b"")
