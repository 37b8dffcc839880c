"""Operations on whole MCAP files: recovery of the readable part of a damaged file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bridge.mcap_reader import McapContents, read_mcap
from bridge.mcap_writer import BulkMcapWriter


def recover(broken: str | Path, fixed: str | Path, *, compression: str = "zstd") -> McapContents:
    """Rewrite everything readable in ``broken`` (schemas, channels, messages of every complete
    chunk, metadata, attachments) into a new, complete and indexed MCAP file ``fixed``.

    Returns what was read from ``broken``. The new file is written beside ``fixed`` and renamed
    into place only when complete.
    """
    contents = read_mcap(broken, strict=False)
    fixed = Path(fixed)
    partial = fixed.with_name(f".{fixed.name}.partial")
    try:
        with BulkMcapWriter(partial, compression=compression, library="pendsim recover") as w:
            for name, values in contents.metadata.items():
                w.add_metadata(name, values)
            for a in contents.attachments.values():
                w.add_attachment(a.name, a.media_type, a.data, a.log_time)
            schema_ids = {
                sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in sorted(contents.schemas.items())
            }
            for cid, ch in sorted(contents.channels.items()):
                new_id = w.register_channel(
                    ch.topic, schema_ids.get(ch.schema_id, 0) or _placeholder(w), ch.message_encoding, ch.metadata
                )
                data = contents.messages.get(cid)
                if data is None or not len(data):
                    continue
                if isinstance(data.payloads, np.ndarray):
                    w.write_messages(new_id, data.log_time_ns, data.payloads, data.publish_time_ns)
                else:  # messages of varying size: runs of equal size
                    sizes = np.array([len(p) for p in data.payloads])
                    edges = np.flatnonzero(np.diff(sizes)) + 1
                    for lo, hi in zip(np.r_[0, edges], np.r_[edges, len(sizes)], strict=True):
                        block = np.frombuffer(b"".join(data.payloads[lo:hi]), np.uint8).reshape(hi - lo, sizes[lo])
                        w.write_messages(new_id, data.log_time_ns[lo:hi], block, data.publish_time_ns[lo:hi])
        partial.replace(fixed)
    finally:
        partial.unlink(missing_ok=True)
    return contents


def _placeholder(w: BulkMcapWriter) -> int:
    """A schema for a channel whose schema record was lost (MCAP needs one to reference)."""
    return w.register_schema("unknown", "", b"")
