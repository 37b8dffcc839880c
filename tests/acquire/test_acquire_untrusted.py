"""acquire treats a CRC-valid packet as untrusted input: every field range-checked, and a packet off
its node's established timeline counted as implausible and dropped without moving the clock fit or
costing a real sample (bridge/acquire/timeline.py).

The truth of the offline cases is the synthetic stream itself: device times on a clock with a
known drift, arrivals = true instant + minimum delay + exponential jitter (+ 80 ms on 2 %), and
which packets were forged. The fit of the same genuine stream without the forged packets is the
reference for "the drift estimate is unaffected"; both are checked against the true drift. The
end-to-end cases run ``pendsim acquire`` as a subprocess on loopback UDP with the emulator's nodes
(its library in a thread) and a thread sending the forged datagrams to m1's port; m2 is the
control. Issue 23 measured, before: one packet with device time 2^63 us or a JSON t_us of 401
digits crashed acquire (OverflowError); ten packets at t_us 2^62 cost 517 of 800 samples and
reported 1000 ppm of drift, exit 0."""

import math
import signal
import socket
import threading
import time

import numpy as np
import pytest
from acquire_helpers import Pendsim, free_udp_ports

from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.emulator import run as run_nodes
from pendsim_bridge.acquire.packets import (
    MALFORMED_REASONS,
    V1_SIZE,
    CsvCodec,
    JsonCodec,
    PacketError,
    StreamFormat,
    Units,
    V1Codec,
)
from pendsim_bridge.acquire.ports import DEFAULT_NODES
from pendsim_bridge.acquire.receiver import WARMUP_S, _Node
from pendsim_bridge.acquire.timeline import IMPLAUSIBLE_REASONS
from pendsim_bridge.cli import build_parser
from pendsim_bridge.commands.nodes import spec_from
from pendsim_bridge.io.recording import read_recording

RATE_HZ = 80.0
# A node at rest (ROW_FIELDS order): unit quaternion, a little rate, gravity on y, calibrated.
ROW = np.array([1, 0, 0, 0, 0.1, 0, 0, 0, 9.81, 0, 0, 0, 0, 0, 9.81, 0, 3, 3, 3, 3], float)
JSON_FIELDS = StreamFormat().fields
CSV_NO_SEQ = ("t_us", "ax", "ay", "az", "gx", "gy", "gz", "qw", "qx", "qy", "qz")


def _v1_with(packet: bytes, offset: int, value: bytes) -> bytes:
    """A pendsim-v1 packet with bytes changed and its CRC made valid again."""
    import zlib

    body = bytearray(packet[: V1_SIZE - 4])
    body[offset : offset + len(value)] = value
    return bytes(body) + zlib.crc32(body).to_bytes(4, "little")


def _json(**changes) -> bytes:
    text = JsonCodec(JSON_FIELDS, Units(), "m1", 1).encode(7, 1_000_000, ROW).decode()
    for key, value in changes.items():
        head, _, rest = text.partition(f'"{key}":')
        text = head + f'"{key}":' + value + rest[rest.index(",") :]
    return text.encode()


V1 = V1Codec(1)


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (V1.encode(7, 2**63, ROW), "bad_time"),  # crashed acquire before (OverflowError)
        (V1.encode(7, 2**52, ROW), "bad_time"),  # a float64 no longer holds it to the microsecond
        (_json(t_us="9" * 401), "bad_time"),  # crashed acquire before (OverflowError)
        (_json(t_us="1e400"), "non_finite"),
        (_json(seq=str(2**53)), "out_of_range"),
        (_json(seq="1" * 401), "out_of_range"),
        (_v1_with(V1.encode(7, 10, ROW), 32, (32767).to_bytes(2, "little", signed=True)), "out_of_range"),  # 36 rad/s
        (_v1_with(V1.encode(7, 10, ROW), 20, (-20000).to_bytes(2, "little", signed=True)), "out_of_range"),  # 20 g
        (_v1_with(V1.encode(7, 10, ROW), 6, bytes([0x02 | 0x08])), "bad_header"),  # a reserved UNIT_SEL bit
        (_v1_with(V1.encode(7, 10, ROW), 7, b"\x01"), "bad_header"),  # the reserved byte
        (CsvCodec(CSV_NO_SEQ, Units(), "m1", 1).encode(0, 5, ROW).replace(b",5.729", b",2100"), "out_of_range"),
    ],
)
def test_a_field_beyond_its_range_is_refused_with_its_reason(data, reason):
    codec = V1 if data[:4] == b"PSIM" else JsonCodec(JSON_FIELDS, Units(), "m1", 1)
    if data[:1] not in (b"P", b"{"):
        codec = CsvCodec(CSV_NO_SEQ, Units(), "m1", 1)
    with pytest.raises(PacketError) as info:
        codec.decode(data)
    assert info.value.reason == reason and reason in MALFORMED_REASONS


def test_the_largest_readings_a_bno055_gives_are_accepted():
    row = ROW.copy()
    row[4:7] = math.radians(2000.0)  # the gyroscope's full scale
    row[7:10] = -16 * 9.80665  # the accelerometer's
    packet = V1.decode(V1.encode(3, 2**52 - 1, row))
    assert packet.device_time_us == 2**52 - 1
    np.testing.assert_allclose(packet.row[4:10], row[4:10], atol=0.01)


# -- the timeline, offline: the real decoder, timeline, clock fit and accounting ----------------


def _genuine(rng, n, drift_ppm, *, jitter_s=1e-3, first_delay_s=0.0):
    device_us = 123_456_789 + np.rint(np.arange(n) * 1e6 / RATE_HZ).astype(np.int64)
    host_s = 1.0 + (device_us - device_us[0]) * 1e-6 / (1 + drift_ppm * 1e-6)
    delay_s = 5e-5 + rng.exponential(jitter_s, n) + np.where(rng.random(n) < 0.02, 0.08, 0.0)
    if first_delay_s:  # the first half second's packets held up, then the queue drains, in order
        held = np.maximum(first_delay_s - np.maximum(np.arange(n) - RATE_HZ / 2, 0) * 0.9 / RATE_HZ, 0.0)
        delay_s += held
    return device_us, host_s + delay_s


def _forged(rng, fmt, count, device_us, arrival_s):
    """Valid-CRC packets with random fields: device time anywhere (a uint64, or within range),
    off the node's timeline (0.1 s to 12 days ahead, 60 s to 12 days behind), and for formats
    with sequence numbers near the timeline with a sequence number 1000 or more away or behind it
    by up to a minute with a random one. Arrive from 0.3 s before the first genuine packet on."""
    codec = StreamFormat(fmt, columns=CSV_NO_SEQ).codec("m1", 1)
    out = []
    for _ in range(count):
        a = float(rng.uniform(arrival_s[0] - 0.3, arrival_s[-1]))
        now_us = int(device_us[0] + (a - arrival_s[0]) * 1e6)
        i = int(np.searchsorted(arrival_s, a))
        kind = int(rng.integers(0, 3 if fmt == "csv" else 5))
        seq = int(rng.integers(0, 2**32))
        if kind == 0:
            t = int(rng.integers(0, 2**63, dtype=np.uint64)) * 2 + int(rng.integers(0, 2))
        elif kind == 1:
            t = int(rng.integers(0, 2**52))
        elif kind == 2:
            ahead = rng.random() < 0.5
            offset_s = 10 ** rng.uniform(-1, 6) if ahead else -(10 ** rng.uniform(math.log10(60), 6))
            t = max(0, now_us + int(offset_s * 1e6))
        elif kind == 3:
            t = now_us + int(rng.integers(-10_000, 10_000))
            seq = (i + int(rng.integers(1000, 2**31)) * int(rng.choice([-1, 1]))) % 2**32
        else:
            t = now_us - int(rng.uniform(0.1, 60) * 1e6)
        row = ROW.copy()
        row[4:7] = rng.uniform(-30, 30, 3)
        if fmt == "pendsim-v1":
            data = codec.encode_many(np.array([seq]), np.array([t], dtype=np.uint64), row[None])[0]
            if rng.random() < 0.1:  # random registers, CRC valid: mostly beyond the chip's ranges
                data = _v1_with(data, 20, rng.bytes(44))
        else:
            data = codec.encode(seq, min(t, 2**63 - 1), row)
        out.append((a, data))
    return out


def _through_acquire_path(fmt, events):
    """Every datagram through ``_Node`` (decode, timeline, clock fit, accounting) in arrival order,
    released as acquire does (after WARMUP_S of fit, and everything at the end); returns the node
    and the device times of the samples released."""
    node = _Node(DEFAULT_NODES[0], StreamFormat(fmt, columns=CSV_NO_SEQ), RATE_HZ, 200_000_000)
    released = []
    for a, data in sorted(events, key=lambda e: e[0]):
        node.receive(data, int(a * 1e9), 0)
        if node.clock.span_s >= WARMUP_S:
            released += node.stream.release(int(a * 1e9))
    node.settle(10**15, 0, final=True)
    released += node.stream.release(10**15, final=True)
    return node, [r.packet.device_time_us for r in released]


@pytest.mark.parametrize("fmt", ["pendsim-v1", "json", "csv"])
def test_thousands_of_forged_packets_cost_no_real_sample_and_move_no_clock(fmt):
    rng = np.random.default_rng({"pendsim-v1": 1, "json": 2, "csv": 3}[fmt])
    drift_ppm = 40.0
    device_us, arrival_s = _genuine(rng, 2400, drift_ppm)
    codec = StreamFormat(fmt, columns=CSV_NO_SEQ).codec("m1", 1)
    genuine = [
        (float(a), codec.encode(k, int(t), ROW)) for k, (t, a) in enumerate(zip(device_us, arrival_s, strict=True))
    ]
    forged = _forged(rng, fmt, 3000, device_us, arrival_s)
    clean, clean_released = _through_acquire_path(fmt, genuine)
    node, released = _through_acquire_path(fmt, genuine + forged)
    assert released == clean_released == device_us.tolist()  # every real sample, once, in order, nothing else
    c = node.stream.counters()
    assert (c.received, c.written, c.lost, c.late, c.duplicated) == (5400, 2400, 0, 0, 0)
    assert c.malformed + c.implausible == 3000  # every forged one counted, by reason
    assert {r for r, _ in c.implausible_reasons} <= set(IMPLAUSIBLE_REASONS) and c.implausible > 1000
    drift = node.line().drift_ppm
    assert drift == clean.line().drift_ppm  # the fit never learned from a forged packet
    assert drift == pytest.approx(drift_ppm, abs=1.0)  # 30 s with 1 ms of jitter (the truth: 40 ppm)


def test_a_network_that_holds_the_first_packets_back_by_300_ms_loses_no_sample():
    """The timeline is established from the first half second, held back 0.3 s above the true
    line; the queue then drains (each packet 11 ms earlier than the one before), and the packets
    after it come on time, 0.3 s "ahead" of that line: they agree with each other and move the fit
    down, and the draining ones, held while the line was above them, are then on it."""
    rng = np.random.default_rng(7)
    device_us, arrival_s = _genuine(rng, 800, -25.0, first_delay_s=0.3)
    codec = V1Codec(1)
    node, released = _through_acquire_path(
        "pendsim-v1",
        [(float(a), codec.encode(k, int(t), ROW)) for k, (t, a) in enumerate(zip(device_us, arrival_s, strict=True))],
    )
    assert released == device_us.tolist() and node.stream.counters().implausible == 0
    assert node.line().drift_ppm == pytest.approx(-25.0, abs=5.0)


def test_a_400_hz_node_across_a_second_of_loss_is_no_sequence_jump():
    """The sequence numbers per device second are measured from the node's own packets, so a
    node faster than --rate-hz (80) keeps its samples across a gap."""
    rng = np.random.default_rng(8)
    n = 2000
    device_us = 5_000_000 + np.arange(n) * 2500
    arrival_s = 2.0 + (device_us - device_us[0]) * 1e-6 + 1e-4 + rng.exponential(2e-4, n)
    keep = (np.arange(n) < 800) | (np.arange(n) >= 1200)  # 400 lost: a second
    codec = V1Codec(1)
    events = [(float(arrival_s[k]), codec.encode(k, int(device_us[k]), ROW)) for k in np.flatnonzero(keep)]
    node, released = _through_acquire_path("pendsim-v1", events)
    assert released == device_us[keep].tolist()
    c = node.stream.counters()
    assert (c.implausible, c.lost) == (0, 400)


# -- end to end: pendsim acquire, loopback UDP, the emulator's nodes and a forger ---------------


def _acquire_with_forger(tmp_path, fmt: str, forge, *, seconds: float = 4.0):
    """``pendsim acquire`` while the emulator's two nodes send ``seconds`` of a release and
    ``forge(send, plan, started_s)`` sends datagrams to m1's port; returns (exit code, stdout,
    stderr, the recording, the plan)."""
    p1, p2 = free_udp_ports(2)
    ports = ["--node", f"m1={p1}", "--node", f"m2={p2}"]
    spec = spec_from(build_parser().parse_args(["nodes", "--duration-s", str(seconds), "--format", fmt, *ports]))
    the_plan = plan(spec)
    acquire = Pendsim(["acquire", "-o", "run.mcap", "--format", fmt, *ports], cwd=tmp_path)
    try:
        acquire.wait_for("listening:")
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            started_s = time.monotonic()
            sender = threading.Thread(target=run_nodes, args=(spec,), kwargs={"say": print, "prepared": the_plan})
            forger = threading.Thread(
                target=forge, args=(lambda data: s.sendto(data, ("127.0.0.1", p1)), the_plan, started_s)
            )
            sender.start()
            forger.start()
            sender.join()
            forger.join()
        acquire.signal(signal.SIGTERM)  # a clean stop: everything waiting is written
        code = acquire.finish()
    finally:
        acquire.kill()
    rec = read_recording(tmp_path / "run.mcap") if code == 0 else None
    return code, "\n".join(acquire.out), "\n".join(acquire.err), rec, the_plan


def _counters(rec, node):
    result = rec.metadata["pendsim/acquisition_result"]
    return {k.split(".", 1)[1]: v for k, v in result.items() if k.startswith(node + ".")}


def _assert_every_real_sample_kept(rec, the_plan, out):
    for stream in the_plan.streams:
        c = _counters(rec, stream.name)
        assert int(c["written"]) == len(stream.seq) == len(rec.imu[stream.name].t_ns), (stream.name, c)
        assert (c["lost"], c["late"], c["duplicated"]) == ("0", "0", "0"), c
        # the emulator's clocks do not drift: what the fit reads is the host's delay jitter over the
        # run (tens of ppm on a quiet machine, hundreds under load), bounded by the jitter the
        # acquisition itself recorded, not by a number for a quiet machine
        span_s = (rec.imu[stream.name].t_ns[-1] - rec.imu[stream.name].t_ns[0]) / 1e9
        allowed_ppm = 60 + 2e3 * float(c["jitter_p99_ms"]) / span_s  # 2 x p99 jitter over the span, in ppm
        assert abs(float(c["drift_ppm"])) < allowed_ppm, (c, allowed_ppm)
    assert "Traceback" not in out


@pytest.mark.parametrize(
    ("fmt", "case", "reason"),
    [
        ("pendsim-v1", "one packet at 2^63 us", "bad_time"),
        ("json", "one t_us of 401 digits", "bad_time"),
        ("pendsim-v1", "ten packets at 2^62 us", "bad_time"),
    ],
)
def test_the_issues_forged_packets_are_counted_and_cost_nothing(tmp_path, fmt, case, reason):
    count = 10 if case.startswith("ten") else 1

    def forge(send, the_plan, started_s):
        time.sleep(1.5)
        seq = int((time.monotonic() - started_s) * RATE_HZ) + 40  # a number the node will send later
        for i in range(count):
            if fmt == "json":
                send(_json(t_us="9" * 401, seq=str(seq)))
            else:
                send(V1Codec(1).encode(seq + i, 2**63 if count == 1 else 2**62, ROW))
            time.sleep(0.05)

    code, out, err, rec, the_plan = _acquire_with_forger(tmp_path, fmt, forge)
    assert code == 0, err
    _assert_every_real_sample_kept(rec, the_plan, err)
    c = _counters(rec, "m1")
    assert c[f"malformed.{reason}"] == str(count) and c["malformed"] == str(count), c
    assert f"malformed: {reason} {count}" in out  # the summary says it


def test_forged_packets_mixed_into_an_emulated_stream_are_counted_and_cost_nothing(tmp_path):
    """A few hundred valid-CRC pendsim-v1 packets with random fields, in range and off the node's
    timeline, sent to m1's port while the emulator's nodes send a release."""
    rng = np.random.default_rng(23)
    sent = []

    def forge(send, the_plan, started_s):
        m1 = the_plan.streams[0]
        codec = V1Codec(1)
        while (elapsed_s := time.monotonic() - started_s) < 3.5:
            now_us = int(m1.device_time_us[0] + elapsed_s * 1e6)
            kind = int(rng.integers(0, 4))
            seq = int(rng.integers(0, 2**32))
            if kind == 0:
                t = int(rng.integers(0, 2**52))
            elif kind == 1:
                t = now_us + int(10 ** rng.uniform(0, 6) * 1e6)  # 1 s to 12 days ahead
            elif kind == 2:
                t = max(0, now_us - int(10 ** rng.uniform(math.log10(60), 6) * 1e6))  # 1 min to 12 days behind
            else:  # on time, with a sequence number 1000 or more away
                t = now_us
                seq = (int(elapsed_s * RATE_HZ) + int(rng.integers(1000, 2**31))) % 2**32
            row = ROW.copy()
            row[4:7] = rng.uniform(-30, 30, 3)
            send(codec.encode(seq, t, row))
            sent.append(kind)
            time.sleep(0.01)

    code, out, err, rec, the_plan = _acquire_with_forger(tmp_path, "pendsim-v1", forge)
    assert code == 0, err
    _assert_every_real_sample_kept(rec, the_plan, err)
    c = _counters(rec, "m1")
    assert len(sent) > 200
    assert int(c["received"]) == len(the_plan.streams[0].seq) + len(sent)
    assert int(c["implausible"]) + int(c["malformed"]) == len(sent), c
    assert int(c["implausible"]) > 100 and "implausible (off the node's timeline): " in out


def test_at_a_stop_the_datagrams_already_arrived_are_read_and_later_ones_left_out():
    """A loop behind the nodes when the stop comes (a busy machine) found a node's last datagram
    still waiting in the OS and lost it (CI, under load: 319 of 320 written). At the stop, what
    arrived before it is read from the real socket; what arrived after it is read and left out.
    (This test read none in CI until ``listen_udp`` waited for the kernel's arrival stamps to be
    on: its datagrams, sent right after the socket opened, were stamped when read, after the stop.)"""
    import selectors

    from pendsim_bridge.acquire.datagrams import listen_udp
    from pendsim_bridge.acquire.receiver import _drain_at_stop

    node = _Node(DEFAULT_NODES[0], StreamFormat("pendsim-v1"), RATE_HZ, 200_000_000)
    node.sock = listen_udp("127.0.0.1", 0, what="the test", option="--node")
    selector = selectors.DefaultSelector()
    selector.register(node.sock, selectors.EVENT_READ, node)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    codec = V1Codec(1)
    try:
        address = node.sock.getsockname()
        for seq in range(3):
            sender.sendto(codec.encode(seq, 1_000_000 + 12_500 * seq, ROW), address)
        # arrived: the kernel stamps a loopback datagram when it delivers it, which on a loaded
        # machine can be well after the send (seen: more than 10 ms)
        assert selector.select(5.0)
        time.sleep(0.05)
        stopped_ns = time.monotonic_ns()
        for seq in range(3, 5):
            sender.sendto(codec.encode(seq, 1_000_000 + 12_500 * seq, ROW), address)
        time.sleep(0.05)
        assert _drain_at_stop(selector, 0, stopped_ns) == 3
        node.settle(10**15, 0, final=True)
        assert node.stream.counters().received == 3
        assert _drain_at_stop(selector, 0, stopped_ns) == 0  # nothing more before the stop
    finally:
        sender.close()
        selector.close()
        node.sock.close()
