"""Scripted replay: order, windows, topics, pacing, MCAP output equal to the input slice,
Rerun output, and bad input."""

import collections
import time

import numpy as np
import pytest
import rerun as rr

from pendsim_bridge.cli import main
from pendsim_bridge.io.mcap.reader import read_mcap
from pendsim_bridge.run.replay import ReplayStats, replay, replay_to_mcap
from pendsim_mj.errors import ParameterError


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "run.mcap"
    assert main(["record", "-o", str(path), "--duration-s", "30"]) == 0
    return path


def _start_ns(path) -> int:
    """The recording's t = 0 (UTC log time, from its metadata)."""
    return int(read_mcap(path).metadata["pendsim/run"]["start_time_ns"])


def test_messages_come_in_log_time_order_within_the_window_and_topics(recording):
    msgs = list(replay(recording, topics=["/imu/m1", "/joint_states"], start_s=5.0, end_s=7.0))
    times = [m.log_time_ns for m in msgs]
    assert times == sorted(times) and msgs[0].t_s >= 5.0 and msgs[-1].t_s <= 7.0
    assert times[0] - _start_ns(recording) == 5_000_000_000  # seconds since the recording's start
    counts = collections.Counter(m.topic for m in msgs)
    assert counts == {"/imu/m1": 161, "/joint_states": 201}  # 80 Hz and 100 Hz over 2 s, both ends included
    first_imu = next(m for m in msgs if m.topic == "/imu/m1")
    contents = read_mcap(recording)
    raw = contents.topic("/imu/m1")
    k = int(np.flatnonzero(raw.log_time_ns == first_imu.log_time_ns)[0])
    assert first_imu.data == raw.payloads[k].tobytes()
    assert first_imu.decoded.header.frame_id == "imu_m1"


class FakeClock:
    """The replay's injectable clock: time moves only when the replay sleeps or the consumer works."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.sleeps: list[float] = []

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.sleeps.append(seconds)
        self.now += seconds


def test_replay_at_real_time_holds_the_schedule(recording):
    # Pacing holds a schedule: message k is due at t0 + (log_k - log_0) / speed. Nothing is early,
    # and a slow consumer (a 0.3 s hiccup at message 100) delays messages only until the schedule
    # catches up: lateness does not accumulate.
    fake = FakeClock()
    stats = ReplayStats()
    t0 = fake.now
    seen = []
    for k, msg in enumerate(
        replay(recording, speed=1.0, start_s=10.0, end_s=20.0, topics=["/imu/m1", "/imu/m2"], stats=stats,
               clock=fake.clock, sleep=fake.sleep)
    ):  # fmt: skip
        seen.append((msg.log_time_ns, fake.now))
        if k == 100:
            fake.now += 0.3  # the consumer stalls
    log = (np.array([s[0] for s in seen]) - seen[0][0]) * 1e-9  # from the first (UTC log times are ~1.8e18 ns)
    due = t0 + (log - log[0])
    at = np.array([s[1] for s in seen])
    assert len(seen) == stats.messages == 2 * 801
    assert np.all(at >= due - 1e-9)  # never early
    late = at - due
    assert np.all(late[:101] < 1e-9)  # exactly on time before the stall
    assert late[101] == pytest.approx(0.3 - (log[101] - log[100]), abs=1e-9)  # the stall itself
    caught_up = np.flatnonzero(log - log[100] > 0.3 + 1e-9)[0]
    assert np.all(late[caught_up:] < 1e-9)  # back on schedule: no accumulated drift
    assert fake.now == pytest.approx(t0 + log[-1] - log[0], abs=1e-9)  # the whole replay took the 10 s span
    summary = stats.summary()
    assert summary.max_ms == pytest.approx(1e3 * late.max(), abs=1e-6)


def test_replay_at_ten_times_speed_takes_a_tenth_of_the_time(recording):
    fake = FakeClock()
    t0 = fake.now
    n = sum(
        1
        for _ in replay(recording, speed=10.0, start_s=0.0, end_s=10.0, topics=["/joint_states"],
                        clock=fake.clock, sleep=fake.sleep)
    )  # fmt: skip
    assert n == 1001
    assert fake.now - t0 == pytest.approx(1.0, abs=1e-9)  # 10 s of data in 1 s, never early


@pytest.mark.parametrize("shift", [False, True])
def test_mcap_output_equals_the_input_slice_message_for_message(recording, tmp_path, shift):
    out = tmp_path / "cut.mcap"
    n = replay_to_mcap(recording, out, topics=["/imu/m2", "/tf"], start_s=12.5, end_s=17.5, shift_to_zero=shift)
    source = read_mcap(recording, strict=True)
    cut = read_mcap(out, strict=True)
    assert cut.complete and set(cut.topics()) == {"/imu/m2", "/tf"} and n == cut.message_count
    start = _start_ns(recording)
    offset = start + int(12.5e9) if shift else 0
    for topic in ("/imu/m2", "/tf"):
        a, b = source.topic(topic), cut.topic(topic)
        keep = (a.log_time_ns >= start + 12.5e9) & (a.log_time_ns <= start + 17.5e9)
        np.testing.assert_array_equal(b.log_time_ns, a.log_time_ns[keep] - offset)
        np.testing.assert_array_equal(b.payloads, a.payloads[keep])
    assert cut.metadata == source.metadata and cut.attachments.keys() == source.attachments.keys()


def test_replay_command_writes_rerun_and_mcap_and_reports_lateness(recording, tmp_path, capsys):
    rrd = tmp_path / "replay.rrd"
    assert main(["replay", str(recording), "--end", "2", "--topics", "/imu/m1", "--rerun", str(rrd), "--quiet"]) == 0
    assert "replayed 161 messages" in capsys.readouterr().out
    rows = collections.Counter()
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        if not chunk.is_static:
            rows[str(chunk.entity_path)] += chunk.num_rows
    assert rows["/replay/imu/m1/gyro"] == rows["/replay/imu/m1/accel"] == 161
    out = tmp_path / "cut.mcap"
    assert main(["replay", str(recording), "--start", "1", "--end", "2", "-o", str(out)]) == 0
    assert read_mcap(out, strict=True).topic("/imu/m1").log_time_ns[0] == _start_ns(recording) + 1_000_000_000
    assert main(["replay", str(recording), "--speed", "20", "--end", "1", "--topics", "/tf"]) == 0
    assert "at 20x; lateness p50" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--topics", "/nope"], "no topic /nope; topics:"),
        (["--start", "5", "--end", "2"], "end_s = 2.0 s is before start_s = 5.0 s"),
        (["--speed", "0"], "--speed must be a number in [0.001, 1e+06] or max"),
        (["--speed", "fast"], "--speed must be a number in [0.001, 1e+06] or max"),
        (["--loop", "-o", "x.mcap"], "--loop cannot write to a file"),
    ],
)
def test_replay_bad_input_is_one_line_exit_2(recording, tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["replay", str(recording), "--quiet", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_replay_refuses_a_damaged_file_before_yielding_anything(recording, tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(recording.read_bytes()[:100_000])
    start = time.perf_counter()
    with pytest.raises(Exception, match=r"bad.mcap: .*recover"):
        next(replay(bad))
    assert time.perf_counter() - start < 10
    with pytest.raises(ParameterError, match="speed must be > 0"):
        next(replay(recording, speed=-1))


def test_loop_starts_again_at_the_beginning_of_the_window(recording):
    stream = replay(recording, topics=["/joint_states"], start_s=1.0, end_s=1.05, loop=True)
    times = [next(stream).log_time_ns - _start_ns(recording) for _ in range(18)]  # 6 per pass, three passes
    assert times[:6] == times[6:12] == times[12:18] == [1_000_000_000 + k * 10_000_000 for k in range(6)]


@pytest.mark.parametrize("how", [["-o", "{out}"], ["--speed", "max", "--quiet"]])
def test_a_window_that_starts_after_the_recording_is_one_line_naming_its_length(recording, tmp_path, capsys, how):
    out = tmp_path / "cut.mcap"
    assert main(["replay", str(recording), "--start", "500", *[a.format(out=out) for a in how]]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and captured.out == "", captured
    assert "the window starts at 500 s, after the end of" in lines[0]
    assert "its messages run from 0 to 30.000 s after its start" in lines[0]
    assert list(tmp_path.iterdir()) == []
    # just inside the end: still a (short) replay
    assert main(["replay", str(recording), "--start", "29.99", "-o", str(out)]) == 0
