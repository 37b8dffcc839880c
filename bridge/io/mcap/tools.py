"""Operations on whole MCAP files: rewriting what was read (all of it, or a selection) into a
new complete file, and recovering the readable part of a damaged one.

Nothing unverified is carried into a new file: content that failed a check is never read, and
content no CRC covers (metadata in a file cut off before its DataEnd, chunks or attachments
whose writer left the CRC at 0, schemas and channels outside chunks) is left out unless the
caller asks to keep it (``keep_unverified``); then the new file lists it in its
``pendsim/unverified`` metadata.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from pendsim_mj.errors import RecordingError

from ..outputs import atomic_output
from .reader import ChannelData, McapContents, read_mcap
from .writer import BulkMcapWriter

UNVERIFIED_METADATA = "pendsim/unverified"


def rewrite(
    contents: McapContents,
    output: str | Path,
    *,
    rows: Callable[[int, ChannelData], np.ndarray | None] | None = None,
    shift_ns: int = 0,
    library: str = "pendsim",
    compression: str = "zstd",
    keep_unverified: bool = False,
    extra_metadata: dict[str, dict[str, str]] | None = None,
) -> int:
    """Write ``contents`` to a new, complete and indexed MCAP file: metadata, attachments,
    schemas, channels, and the messages ``rows(channel_id, data)`` chooses (indices; None drops
    the channel; default all), log times moved back by ``shift_ns``. Unverified content is left
    out (or, with ``keep_unverified``, kept and listed in ``pendsim/unverified``). The file is
    published only when complete and never over an existing file. Returns the messages written."""
    unverified = {(u.kind, u.name) for u in contents.unverified}
    written = 0
    with atomic_output(output) as partial, BulkMcapWriter(partial, compression=compression, library=library) as w:
        for name, values in contents.metadata.items():
            if keep_unverified or ("metadata", name) not in unverified:
                w.add_metadata(name, values)
        for name, values in (extra_metadata or {}).items():
            w.add_metadata(name, values)
        if keep_unverified and contents.unverified:
            w.add_metadata(UNVERIFIED_METADATA, {str(k): str(u) for k, u in enumerate(contents.unverified)})
        for a in contents.attachments.values():
            if keep_unverified or ("attachment", a.name) not in unverified:
                w.add_attachment(a.name, a.media_type, a.data, a.log_time)
        schema_ids = {
            sid: w.register_schema(s.name, s.encoding, s.data)
            for sid, s in sorted(contents.schemas.items())
            if keep_unverified or ("schema", str(sid)) not in unverified
        }
        for cid, ch in sorted(contents.channels.items()):
            if not keep_unverified and ("channel", str(cid)) in unverified:
                continue
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
    return written


def _write_rows(w: BulkMcapWriter, channel_id: int, data: ChannelData, index: np.ndarray, shift_ns: int) -> int:
    if not len(index):
        return 0
    log, pub = data.log_time_ns[index] - shift_ns, data.publish_time_ns[index] - shift_ns
    log, pub = np.maximum(log, 0), np.maximum(pub, 0)
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


def recover(
    broken: str | Path, fixed: str | Path, *, compression: str = "zstd", keep_unverified: bool = False
) -> McapContents:
    """Rewrite everything readable and verified in ``broken`` (every chunk whose CRC checks,
    found again after damaged records; metadata, attachments, schemas and channels) into a new,
    complete and indexed MCAP file ``fixed``. Content no CRC covers is left out unless
    ``keep_unverified`` (then listed in ``pendsim/unverified``). Returns what was read."""
    contents = read_mcap(broken, strict=False, verified_only=not keep_unverified)
    if contents.message_count == 0:
        problem = f": {contents.problems[0]}" if contents.problems else ""
        raise RecordingError(f"{broken}: no message to recover{problem} (nothing written)")
    rewrite(contents, fixed, library="pendsim recover", compression=compression, keep_unverified=keep_unverified)
    return contents


def _placeholder(w: BulkMcapWriter) -> int:
    """A schema for a channel whose schema record was lost (MCAP needs one to reference)."""
    return w.register_schema("unknown", "", b"")
