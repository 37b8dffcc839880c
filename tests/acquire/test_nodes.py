"""The node emulator's plan: samples at each node's own clock instants with the simulated rig's
values, faults as logged, and malformed datagrams that the receiver refuses for the logged reason."""

import dataclasses
import socket

import numpy as np
import pytest

from pendsim_bridge.acquire.emulator import EmulatorSpec, Faults, NodeClock, fused_samples, plan, run
from pendsim_bridge.acquire.packets import ROW_FIELDS, PacketError, StreamFormat
from pendsim_bridge.acquire.ports import NodeSpec
from pendsim_bridge.run.record import RecordSpec, simulate_for
from pendsim_mj.sensors.bno055 import Bno055

RUN = RecordSpec(duration_s=2.0, hold_s=1.0, imu=Bno055(noise=False))


@pytest.fixture(scope="module")
def samples():
    return fused_samples(RUN)


def test_each_node_samples_on_its_own_clock_with_the_rigs_values(samples):
    clocks = (("m1", NodeClock(300.0, 100.0, 0.004)), ("m2", NodeClock(-200.0, 55.5, 0.0111)))
    the_plan = plan(EmulatorSpec(RUN, clocks=clocks), samples)
    traj = simulate_for(RUN)  # the same run, straight from the simulation (no sensor model in between)
    for k, (stream, (_, clock)) in enumerate(zip(the_plan.streams, clocks, strict=True)):
        rate = 1 + clock.drift_ppm * 1e-6
        # device time: the node's clock at its sample instants, exactly k/80 s apart on that clock
        np.testing.assert_array_equal(np.diff(stream.device_time_us), 12500)
        assert stream.device_time_us[0] == round((clock.offset_s + rate * clock.phase_s) * 1e6)
        # true instants: phase + n / (80 (1 + drift))
        np.testing.assert_allclose(stream.t_s, clock.phase_s + np.arange(len(stream.t_s)) / (80 * rate), atol=1e-12)
        assert stream.t_s[-1] <= RUN.hold_s + RUN.duration_s < stream.t_s[-1] + 1 / 80
        # values: the latest 10 ms simulation instant at or before each sample, after the release
        after = stream.t_s >= RUN.hold_s
        step = np.floor((stream.t_s[after] - RUN.hold_s) * 100 + 1e-9).astype(int)
        gyro_z = stream.rows[after, ROW_FIELDS.index("gz")]
        np.testing.assert_allclose(gyro_z, traj.imu_gyro_rad_s[step, k, 2], atol=1e-12)
        assert np.all(stream.rows[~after, ROW_FIELDS.index("gz")] == 0.0)  # held still


def test_jitter_delays_packets_first_in_first_out_and_reorder_moves_them_by_the_depth(samples):
    spec = EmulatorSpec(RUN, faults=Faults(reorder=0.05, reorder_depth=3, jitter_ms=5.0, loss=0.02), seed=2)
    the_plan = plan(spec, samples)
    for node in ("m1", "m2"):
        sent = [d for d in the_plan.datagrams if d.node == node and d.sent]
        plain = [d.seq for d in sent if not d.reordered]
        assert plain == sorted(plain)  # jitter alone never reorders
        order = [d.seq for d in sent]
        moved = [d for d in sent if d.reordered]
        assert len(moved) > 3
        reordered = {d.seq for d in moved}
        for d in moved:
            later = [s for s in order[: order.index(d.seq)] if s > d.seq]
            following = sorted(s for s in order if s > d.seq)[:3]
            if following and not reordered & set(following):
                assert len(later) == len(following)  # sent right after the next 3
            else:  # a neighbour was held back too: it goes at that neighbour's own time
                assert 1 <= len(later) <= 3
        lost = [d for d in the_plan.datagrams if d.node == node and not d.sent]
        assert lost and all(d.payload == b"" for d in lost)


FORMATS = [
    StreamFormat(),
    StreamFormat("csv"),
    StreamFormat("csv", columns=("node", "seq", "t_us", "_", *ROW_FIELDS)),
    StreamFormat("json"),
    StreamFormat("json", fields=(("t_ms", "time"), ("gx", "w/x"), ("gy", "w/y"), ("gz", "w/z"))),
]


@pytest.mark.parametrize("stream", FORMATS, ids=lambda f: f"{f.format}-{len(f.columns)}-{len(f.fields)}")
def test_every_malformed_datagram_is_refused_for_the_reason_the_log_gives(samples, stream):
    spec = EmulatorSpec(RUN, stream=stream, faults=Faults(malformed=0.5), seed=5)
    the_plan = plan(spec, samples)
    codecs = {n.name: stream.codec(n.name, n.node_id) for n in spec.nodes}
    reasons = set()
    for d in the_plan.datagrams:
        if d.kind == "malformed":
            with pytest.raises(PacketError) as info:
                codecs[d.node].decode(d.payload)
            assert info.value.reason == d.reason
            reasons.add(d.reason)
        else:
            codecs[d.node].decode(d.payload)
    assert len(reasons) >= 4


def test_sending_holds_the_schedule(samples):
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    port = receiver.getsockname()[1]
    run_spec = dataclasses.replace(RUN, duration_s=0.5, hold_s=0.5)
    spec = EmulatorSpec(run_spec, nodes=(NodeSpec("m1", port),), rate_hz=400.0)
    try:
        result = run(spec, say=lambda line: None)
    finally:
        receiver.close()
    assert result.completed and result.sent["m1"] == 400
    # One schedule from the start: the run ends with its last packet, lateness does not add up.
    assert result.duration_s < 1.0 + 0.25


def test_nodes_help_says_which_log_files_it_writes(capsys):
    from pendsim_bridge.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["nodes", "--help"])
    assert stop.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--log FILE.jsonl|FILE.csv" in text and "JSON lines (.jsonl) or CSV (.csv)" in text
