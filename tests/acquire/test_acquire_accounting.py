"""Per-node accounting and the reorder window, without sockets: arrivals are scripted with their
times, and the released order and the counters are checked against what was scripted."""

import numpy as np
import pytest

from pendsim_bridge.acquire.accounting import NodeStream
from pendsim_bridge.acquire.packets import Packet

MS = 1_000_000
ROW = (0.0,) * 20


def _packet(seq, t_us=None):
    return Packet(seq, seq * 12500 if t_us is None else t_us, ROW)


def _run(arrivals, *, window_ms=100, modulus=None):
    """Offer (seq, arrival ms) in order, releasing every 10 ms; return released seqs and the stream."""
    stream = NodeStream(window_ns=window_ms * MS, seq_modulus=modulus)
    released = []
    clock = 0
    for seq, at_ms in arrivals:
        while clock < at_ms:
            released += [a.seq for a in stream.release(clock * MS)]
            clock += 10
        stream.offer(_packet(seq), at_ms * MS)
        released += [a.seq for a in stream.release(at_ms * MS)]
    released += [a.seq for a in stream.release((clock + 10_000) * MS)]
    return released, stream.counters()


def test_an_in_order_stream_is_released_at_once_and_counts_nothing_else():
    stream = NodeStream(window_ns=100 * MS)
    for seq in range(5):
        stream.offer(_packet(seq), seq * 12 * MS)
    stream.release(0)  # the first packet waits the window (nothing before it is known)
    out = stream.release(101 * MS)
    assert [a.seq for a in out] == [0, 1, 2, 3, 4]
    stream.offer(_packet(5), 200 * MS)
    assert [a.seq for a in stream.release(200 * MS)] == [5]  # contiguous: no waiting
    c = stream.counters()
    assert (c.received, c.written, c.lost, c.duplicated, c.reordered, c.late, c.malformed) == (6, 6, 0, 0, 0, 0, 0)


def test_a_reordered_packet_within_the_window_is_written_in_order():
    released, c = _run([(0, 0), (1, 12), (3, 37), (2, 50), (4, 50)])
    assert released == [0, 1, 2, 3, 4]
    assert (c.reordered, c.lost, c.late) == (1, 0, 0)


def test_a_gap_becomes_lost_after_the_window_and_a_latecomer_moves_to_late():
    released, c = _run([(0, 0), (1, 12), (3, 37), (4, 50), (5, 62), (2, 400), (6, 400)])
    assert released == [0, 1, 3, 4, 5, 6]
    assert (c.lost, c.late, c.reordered, c.written, c.received) == (0, 1, 0, 6, 7)
    released, c = _run([(0, 0), (1, 12), (3, 37), (4, 50)])
    assert (c.lost, c.late) == (1, 0)


def test_duplicates_are_counted_once_and_never_released_twice():
    released, c = _run([(0, 0), (1, 12), (1, 13), (2, 25), (0, 300), (2, 300), (3, 300)])
    assert released == [0, 1, 2, 3]
    assert (c.duplicated, c.late, c.lost) == (3, 0, 0)


def test_malformed_datagrams_are_counted_by_reason():
    stream = NodeStream(window_ns=0)
    stream.count_malformed("crc")
    stream.count_malformed("crc")
    stream.count_malformed("truncated")
    c = stream.counters()
    assert (c.received, c.malformed, c.malformed_reasons) == (3, 3, (("crc", 2), ("truncated", 1)))
    assert c.as_dict()["malformed.crc"] == 2


def test_pendsim_v1_sequence_numbers_wrap_at_two_to_the_32():
    start = 2**32 - 3
    arrivals = [((start + i) % 2**32, 12 * i) for i in range(6)]
    released, c = _run(arrivals, modulus=2**32)
    assert released == [start + i for i in range(6)]  # unwrapped: still increasing
    assert (c.lost, c.reordered, c.duplicated) == (0, 0, 0)


def test_formats_without_sequence_numbers_are_numbered_from_device_time():
    stream = NodeStream(window_ns=0, rate_hz=80.0)
    for k in (0, 1, 2, 4, 4, 5):
        stream.offer(Packet(None, 1_000_000 + k * 12500 + (3 if k % 2 else -2), ROW), k * MS)
    out = stream.release(10**12, final=True)
    assert [a.seq for a in out] == [0, 1, 2, 4, 5]
    c = stream.counters()
    assert (c.lost, c.duplicated) == (1, 1)


@pytest.mark.parametrize("seed", range(20))
def test_counters_match_a_random_stream_exactly(seed):
    """Random loss, duplicates and displacement smaller than the window: every sequence number is
    written once, in order, and the counters equal what the script did."""
    rng = np.random.default_rng(seed)
    n = 2000
    sent = []  # (arrival ms, seq)
    lost = set()
    for k in range(n):
        if 0 < k < n - 1 and rng.random() < 0.05:
            lost.add(k)
            continue
        at = 12.5 * k + (rng.uniform(0, 60) if rng.random() < 0.03 else 0.0)  # displaced up to 60 ms
        sent.append((at, k))
        if rng.random() < 0.01:
            sent.append((at + rng.uniform(0, 30), k))  # a duplicate
    sent.sort()
    arrivals = [(seq, at) for at, seq in sent]
    released, c = _run(arrivals, window_ms=100)
    expected_reordered = 0
    highest, seen = -1, set()
    for seq, _ in arrivals:
        if seq in seen:
            continue
        seen.add(seq)
        expected_reordered += seq < highest
        highest = max(highest, seq)
    assert released == sorted(set(range(n)) - lost)
    assert c.lost == len(lost) and c.late == 0
    assert c.duplicated == len(arrivals) - len(seen)
    assert c.reordered == expected_reordered
    assert c.written + c.lost == n and c.received == len(arrivals)


def test_the_file_is_written_up_to_where_every_sending_node_has_released():
    from types import SimpleNamespace

    from pendsim_bridge.acquire.receiver import STALE_S, _settled_ns

    now = 100 * 10**9
    long_ago = now - int((STALE_S + 1) * 1e9)  # the start, for a node not heard from since
    just = now - int((STALE_S - 1) * 1e9)
    active = lambda last_log: SimpleNamespace(last_sample_ns=now - 10**8, last_log_ns=last_log)  # noqa: E731
    silent = SimpleNamespace(last_sample_ns=long_ago, last_log_ns=5)
    never = SimpleNamespace(last_sample_ns=0, last_log_ns=-1)  # no valid packet yet (malformed ones or none)
    assert _settled_ns([active(70), active(90)], now, long_ago) == 70  # the slower node bounds it
    assert _settled_ns([active(70), silent], now, long_ago) == 70  # a silent node holds nothing back
    assert _settled_ns([active(70), active(-1)], now, long_ago) == -1  # one still warming up holds everything
    assert _settled_ns([never, silent], now, long_ago) is None  # nobody sending: write everything given
    # A node not heard from yet holds everything back for STALE_S after the start (its first
    # samples may be older than the others'), then no longer.
    assert _settled_ns([active(70), never], now, just) == -1
    assert _settled_ns([active(70), never], now, long_ago) == 70
