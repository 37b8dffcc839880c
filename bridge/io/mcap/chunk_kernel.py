"""A chunk's message index checked against its records, compiled by numba (``McapFile.chunks``
with ``compiled=True``; this module is imported only then: numba stays out of a process that
does not ask for it).

``index_messages`` does in one compiled pass what ``extract._messages_by_index`` does with
about 40 numpy calls per chunk (with the wanted channels' payloads gathered, a 6 h static
recording's chunks of about 7200 messages took 0.5-0.6 ms each instead of 2.2-2.4 ms): it walks the chunk's
records from the first message to the end, each of which must be a Message record inside the
chunk (so together they tile it exactly), and checks that the message index lists every one of
them exactly once with its channel and log time (each channel's entries in chunk order, as
writers put them; another order goes to numpy, which sorts). Where anything differs it answers -1 and the
caller parses the chunk with numpy, which names the problem; a chunk it accepts gives the same
messages in the same order as the numpy path (tests/io/test_chunk_kernel.py compares them).
"""

from __future__ import annotations

import numba
import numpy as np

from pendsim_mj import compile_notice

from ...signals import interrupts_deferred

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)

MESSAGE_OPCODE = 0x05
RECORD_HEAD_SIZE = 9  # opcode (1), length (8)
MESSAGE_FIELDS_SIZE = 22  # channel (2), sequence (4), log time (8), publish time (8)


@numba.njit(cache=True, nogil=True)
def _u64(data: np.ndarray, at: int) -> np.int64:  # pragma: no cover - compiled
    """The little-endian 64-bit integer at data[at:at + 8] (as int64: wraps above 2**63 - 1, as
    numpy's astype(np.int64) of the uint64 does)."""
    value = np.int64(0)
    for b in range(8):
        value |= np.int64(data[at + b]) << np.int64(8 * b)
    return value


@numba.njit(cache=True, nogil=True)
def index_messages(
    raw: np.ndarray,
    file: np.ndarray,
    spans: np.ndarray,
    slot: np.ndarray,
    row_of: np.ndarray,
    offsets: np.ndarray,
    log_ns: np.ndarray,
    publish_ns: np.ndarray,
    sizes: np.ndarray,
    counts: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Check a chunk's message index against its records and list the wanted channels' messages.

    Args:
      raw: (u,) uint8, the uncompressed chunk.
      file: (f,) uint8, bytes of the file holding the chunk's MessageIndex records.
      spans: (c, 3) int64, one row per MessageIndex record of the chunk: channel id, the byte
        offset of its entries in ``file``, their count.
      slot: (65536,) int64, the output row of each wanted channel id, -1 for the others.
      row_of: (65536,) int64: the spans' row of each of their channel ids, -1 for the others.
      offsets, log_ns, publish_ns, sizes: (w, capacity) int64 outputs: per wanted channel, its
        messages' offsets in the chunk, log and publish times, and data sizes, in chunk order.
      counts: (w,) int64 outputs: messages written per wanted channel.

    Returns:
      The offset of the first message (the records before it are the chunk's leading Schema and
      Channel records), or -1 if the index does not list exactly the chunk's messages, each
      channel's in chunk order (then nothing is to be trusted of the outputs).
    """
    counts[:] = 0
    rows = spans.shape[0]
    used = np.zeros(rows, np.int64)  # entries matched so far, per index record
    first = raw.shape[0]
    for r in range(rows):
        if spans[r, 2] > 0:
            first = min(first, _u64(file, spans[r, 1] + 8))
    if first < 0 or first == raw.shape[0]:
        return -1
    # the records from the first message to the end, each a Message inside the chunk, and each the
    # next entry of its channel's index record (the same offset and log time)
    at = first
    while at < raw.shape[0]:
        if at + RECORD_HEAD_SIZE + MESSAGE_FIELDS_SIZE > raw.shape[0]:
            return -1
        length = _u64(raw, at + 1)
        if raw[at] != MESSAGE_OPCODE or length < MESSAGE_FIELDS_SIZE or length > raw.shape[0] - at - RECORD_HEAD_SIZE:
            return -1
        channel = np.int64(raw[at + 9]) | (np.int64(raw[at + 10]) << 8)
        r = row_of[channel]
        if r < 0 or used[r] == spans[r, 2]:
            return -1
        entry = spans[r, 1] + 16 * used[r]
        stamp = _u64(raw, at + 15)
        if _u64(file, entry + 8) != at or _u64(file, entry) != stamp:
            return -1
        used[r] += 1
        w = slot[channel]
        if w >= 0:
            k = counts[w]
            offsets[w, k] = at
            log_ns[w, k] = stamp
            publish_ns[w, k] = _u64(raw, at + 23)
            sizes[w, k] = length - MESSAGE_FIELDS_SIZE
            counts[w] = k + 1
        at += RECORD_HEAD_SIZE + length
    for r in range(rows):  # every entry listed a message
        if used[r] != spans[r, 2]:
            return -1
    return first


def warm_up() -> None:
    """Call the kernel once on a one-message chunk: numba's first call in a process loads its
    compiled code (0.3-0.5 s, the first of any numba function), with Ctrl-C held back until it
    is done (``interrupts_deferred``: numba's callbacks would swallow it)."""
    with interrupts_deferred():
        _call_once()


def _call_once() -> None:
    """The kernel on a chunk of one message, its index listing it; the chunk and the file as
    read-only arrays, as the reader passes them (numba compiles each kind apart)."""
    chunk = np.zeros(RECORD_HEAD_SIZE + MESSAGE_FIELDS_SIZE, np.uint8)
    chunk[0] = MESSAGE_OPCODE
    chunk[1] = MESSAGE_FIELDS_SIZE
    raw = np.frombuffer(chunk.tobytes(), np.uint8)
    file = np.frombuffer(bytes(16), np.uint8)
    out = np.zeros((1, 1), np.int64)
    slot, row_of = np.full((2, 1 << 16), -1, np.int64)
    row_of[0] = 0
    index_messages(raw, file, np.array([[0, 0, 1]], np.int64), slot, row_of, out, out, out, out, np.zeros(1, np.int64))
