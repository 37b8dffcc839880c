"""The clock fit: device time to host time under network delays that only ever add time.

The synthetic truth: host = a + x / (1 + drift) for a node whose clock gains ``drift``; each
arrival adds a minimum delay and a random one (exponential, plus bursts of 100 ms on some packets).
"""

import socket
import time

import numpy as np
import pytest

from pendsim_bridge.acquire.clock import MAX_DRIFT_PPM, ClockFit, residuals_s
from pendsim_mj.estimation.timing import ClockRelation


def _arrivals(seed: int, drift_ppm: float, *, duration_s=60.0, rate_hz=80.0, jitter_s=5e-3, bursts=0.1):
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    device = 412.345 + np.arange(n) / rate_hz  # the node's clock, s
    true_host = 3.0 + (device - device[0]) / (1 + drift_ppm * 1e-6)
    delay = 3e-4 + rng.exponential(jitter_s, n) + np.where(rng.random(n) < bursts, 0.1, 0.0)
    return device, true_host, true_host + delay


def _fit(device, arrival):
    fit = ClockFit()
    for x, y in zip(device, arrival, strict=True):
        fit.add(float(x), float(y))
    return fit.relation()


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("drift_ppm", [-80.0, 0.0, 45.0])
def test_fit_recovers_drift_and_time_under_jitter_and_bursts(seed, drift_ppm):
    device, true_host, arrival = _arrivals(seed, drift_ppm)
    line = _fit(device, arrival)
    assert line.drift_ppm == pytest.approx(drift_ppm, abs=0.5)
    # Mapped times sit on the true send times plus the minimum delay (0.3 ms), to tens of us.
    error = np.asarray(line.to_recorder(device)) - (true_host + 3e-4)
    assert np.max(np.abs(error)) < 60e-6


def test_jitter_does_not_move_the_fit_while_least_squares_follows_it():
    device, true_host, arrival = _arrivals(11, 20.0, jitter_s=20e-3, bursts=0.3)
    quiet = _fit(device, true_host + 3e-4)  # every packet at the minimum delay
    noisy = _fit(device, arrival)
    moved = np.max(np.abs(np.asarray(noisy.to_recorder(device)) - np.asarray(quiet.to_recorder(device))))
    assert moved < 100e-6
    slope, offset = np.polyfit(device, arrival, 1)  # what a least-squares fit of arrivals would say
    least_squares_error = np.mean(slope * device + offset - true_host)
    assert least_squares_error > 0.04  # it follows the mean delay (20 ms + 30 % of 100 ms)


def test_residuals_are_the_delays_beyond_the_minimum():
    device, _, arrival = _arrivals(12, -30.0, jitter_s=2e-3, bursts=0.0)
    line = _fit(device, arrival)
    residual = residuals_s(line, device, arrival)
    assert residual.min() > -20e-6
    assert np.median(residual) == pytest.approx(2e-3 * np.log(2), rel=0.1)  # median of the exponential


def test_reordered_and_duplicated_points_are_skipped():
    fit = ClockFit()
    for x, y in [(0.0, 1.0), (1.0, 2.0), (0.5, 1.0), (1.0, 1.5), (2.0, 3.0)]:
        fit.add(x, y)
    assert fit.count == 3  # (0.5, 1.0) came after 1.0; (1.0, 1.5) repeats a device time
    assert fit.relation().to_recorder(2.0) == pytest.approx(3.0)


def test_slope_stays_within_the_drift_bound_early_in_a_run():
    fit = ClockFit()
    fit.add(0.0, 0.050)  # a delayed first packet
    fit.add(0.0125, 0.0126)  # then one on time: the edge's slope is far from 1
    assert abs(fit.relation().drift_ppm) <= MAX_DRIFT_PPM + 1e-6
    single = ClockFit()
    single.add(5.0, 7.0)
    assert single.relation().rate == 1.0 and single.relation().to_recorder(6.0) == pytest.approx(8.0)


def _stamping_node():
    from pendsim_bridge.acquire.packets import StreamFormat
    from pendsim_bridge.acquire.ports import DEFAULT_NODES
    from pendsim_bridge.acquire.receiver import _Node

    return _Node(DEFAULT_NODES[0], StreamFormat(), 80.0, 200_000_000)


def test_header_stamps_keep_device_time_while_log_times_follow_the_learning_fit():
    """The log times of successive batches come from a fit that still moves (here +250 ppm, then a
    step back of 70 us, as early in a real run); the header stamps stay the device times at rate 1
    from the first sample's log time, whatever the fit does."""
    from pendsim_bridge.acquire.receiver import _device_stamps

    node = _stamping_node()
    device_us = 300_000_000 + 12_500 * np.arange(120, dtype=np.int64)
    log_ns = 5_000_000_000 + np.rint(12_500_000 * (1 + 250e-6) * np.arange(120)).astype(np.int64)
    log_ns[60:] -= 70_000
    stamps = np.concatenate(
        [_device_stamps(node, device_us[:60], log_ns[:60]), _device_stamps(node, device_us[60:], log_ns[60:])]
    )
    np.testing.assert_array_equal(stamps, log_ns[0] + (device_us - device_us[0]) * 1000)


def test_header_stamps_increase_across_a_node_restart():
    """A node that reboots (its device time starts again near zero) gets a new stamp origin at its
    first sample after the restart: stamps strictly increase and stay on its log times."""
    from pendsim_bridge.acquire.receiver import _device_stamps

    node = _stamping_node()
    device_us = np.concatenate([900_000_000 + 12_500 * np.arange(50), 1_000 + 12_500 * np.arange(50)]).astype(np.int64)
    log_ns = 5_000_000_000 + 12_500_000 * np.arange(100, dtype=np.int64)
    stamps = _device_stamps(node, device_us, log_ns)
    assert np.all(np.diff(stamps) > 0)
    np.testing.assert_array_equal(stamps[50:] - stamps[50], (device_us[50:] - device_us[50]) * 1000)
    assert stamps[50] == log_ns[50]


def test_a_clock_map_done_in_place_gives_the_same_instants_in_the_stamps_own_array():
    # the truth: the map written out, recorder = offset + rate (stamp - stamp0), on a new array
    relation = ClockRelation(offset_s=1.7e9 + 0.123456789, rate=1.0 + 37e-6, stamp0_s=12.345)
    stamps = 12.345 + np.cumsum(np.random.default_rng(4).uniform(0.011, 0.014, 100_000))
    expected = 1.7e9 + 0.123456789 + (1.0 + 37e-6) * (stamps - 12.345)
    own = stamps.copy()
    mapped = relation.to_recorder_in_place(own)
    assert mapped is own
    np.testing.assert_array_equal(mapped, expected)
    np.testing.assert_array_equal(relation.to_recorder(stamps), expected)


class _PausedClocks:
    """time.monotonic_ns and time.time_ns of a process paused ``pause_ns`` between the two calls
    of the first reading (a busy machine's preemption, a profiler's stop); the real-time clock is
    ``offset_ns`` behind the monotonic one."""

    def __init__(self, offset_ns: int, pause_ns: int) -> None:
        self.now_ns, self.offset_ns, self.pause_ns, self.calls = 5_000_000_000, offset_ns, pause_ns, 0

    def monotonic_ns(self) -> int:
        self.now_ns += 300
        return self.now_ns

    def time_ns(self) -> int:
        self.calls += 1
        self.now_ns += 300 + (self.pause_ns if self.calls == 1 else 0)
        return self.now_ns - self.offset_ns


def test_a_pause_between_the_two_clocks_readings_does_not_move_arrival_times(monkeypatch):
    from pendsim_bridge.acquire import datagrams

    clocks = _PausedClocks(offset_ns=1_234_567_890, pause_ns=5_000_000)
    monkeypatch.setattr(datagrams.time, "monotonic_ns", clocks.monotonic_ns)
    monkeypatch.setattr(datagrams.time, "time_ns", clocks.time_ns)
    # read once, the 5 ms pause put every packet of the read 5 ms early; the narrowest of the
    # brackets is off by at most half its width (0.3 us here)
    assert abs(datagrams.realtime_to_monotonic_ns() - clocks.offset_ns) <= 1_000
    assert clocks.calls >= 2


def test_loopback_arrival_stamps_lie_between_the_send_and_the_read():
    from pendsim_bridge.acquire.datagrams import listen_udp, read_stamped

    sock = listen_udp("127.0.0.1", 0, what="the test", option="--port")
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        port = sock.getsockname()[1]
        windows = []
        for k in range(50):
            sent_ns = time.monotonic_ns()
            sender.sendto(b"x%d" % k, ("127.0.0.1", port))
            got = []
            while not got:
                got = read_stamped(sock)
            windows.append((sent_ns, got[0].arrival_ns, time.monotonic_ns()))
        for sent_ns, arrival_ns, read_ns in windows:
            # the kernel's real-time stamp mapped onto the monotonic clock: after the send (to the
            # mapping's error, a few us) and before the read returned
            assert sent_ns - 50_000 <= arrival_ns <= read_ns
    finally:
        sock.close()
        sender.close()


def test_a_datagram_that_waited_since_just_after_the_socket_opened_keeps_its_arrival_stamp():
    """Linux switches arrival stamps on for the whole host lazily, when the first socket asks: a
    datagram that arrives before then is stamped when it is read. On a host with no other
    stamping socket (a CI worker) the datagrams sent right after ``listen_udp`` and read 50 ms
    later carried stamps 50 ms late, and a stop's drain took them for datagrams that came after
    the stop (CI, three times). ``listen_udp`` returns with the stamps on."""
    import selectors

    from pendsim_bridge.acquire.datagrams import listen_udp, read_stamped

    sock = listen_udp("127.0.0.1", 0, what="the test", option="--port")
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    selector = selectors.DefaultSelector()
    selector.register(sock, selectors.EVENT_READ)
    try:
        sender.sendto(b"x", sock.getsockname())
        assert selector.select(5.0)
        seen_ns = time.monotonic_ns()  # it had arrived by now
        time.sleep(0.05)
        (got,) = read_stamped(sock)
        assert got.arrival_ns <= seen_ns + 50_000  # the mapping's error, a few us
    finally:
        selector.close()
        sock.close()
        sender.close()


def test_a_stamp_maps_to_the_same_instant_as_a_float_and_in_an_array():
    """``ClockRelation.to_recorder`` on one float (the live loop, a packet at a time) gives a float,
    the same number as the array form gives for it."""
    from pendsim_mj.estimation.timing import ClockRelation

    relation = ClockRelation(offset_s=12.5, rate=1.0 + 37e-6, stamp0_s=1000.25)
    stamps = np.array([0.0, 1000.25, 1234.5678, 86400.125])
    mapped = relation.to_recorder(stamps)
    for stamp, expected in zip(stamps.tolist(), mapped.tolist(), strict=True):
        one = relation.to_recorder(stamp)
        assert isinstance(one, float) and one == expected
    assert mapped[1] == 12.5 and mapped[2] == pytest.approx(12.5 + (1234.5678 - 1000.25) * (1 + 37e-6), abs=1e-12)
