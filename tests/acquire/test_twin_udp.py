"""pendsim twin on live packets over real loopback UDP (the emulator in this process, the twin a
real subprocess): scripted faults named on the right parameter or node, and a replay of the twin's
own recording giving its live estimates and alarms again, exactly; a killed twin leaves a
recoverable file that lacks at most about a second; a port in use is one line."""

from __future__ import annotations

import json
import math
import signal
import socket
import threading
import time

import numpy as np
import pytest
from acquire_helpers import Pendsim, free_udp_ports
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.emulator import run as run_nodes
from pendsim_bridge.cli import build_parser, main
from pendsim_bridge.commands.nodes import spec_from
from pendsim_bridge.io import twin_topics
from pendsim_bridge.io.recording import read_recording


def _emulate(args: list[str]) -> threading.Thread:
    spec = spec_from(build_parser().parse_args(["nodes", *args]))
    thread = threading.Thread(target=run_nodes, args=(spec,), kwargs={"say": print, "prepared": plan(spec)})
    thread.start()
    return thread


def _estimates(path) -> np.ndarray:
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        rows = [[m.log_time, *msg.data] for _, _, m, msg in reader.iter_decoded_messages([twin_topics.ESTIMATE_TOPIC])]
    return np.array(rows, dtype=float)


def _metadata(path) -> dict[str, dict[str, str]]:
    with open(path, "rb") as f:
        return {m.name: m.metadata for m in make_reader(f).iter_metadata()}


def test_a_killed_twin_leaves_a_recoverable_file_that_lacks_at_most_about_a_second(tmp_path):
    p1, p2 = free_udp_ports(2)
    ports = ["--node", f"m1={p1}", "--node", f"m2={p2}"]
    twin = Pendsim(["twin", "-o", "live.mcap", *ports], cwd=tmp_path)
    try:
        twin.wait_for("twin: listening")
        sender = _emulate(["--duration-s", "6", "--hold-s", "1", *ports])
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob(".live.mcap.*.partial.mcap")) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(4.0)
        twin.signal(signal.SIGKILL)
        assert twin.finish() == -signal.SIGKILL
        sender.join()
    finally:
        twin.kill()
    assert not (tmp_path / "live.mcap").exists()
    (partial,) = tmp_path.glob(".live.mcap.*.partial.mcap")
    assert main(["recover", str(partial), str(tmp_path / "fixed.mcap")]) == 0
    rec = read_recording(tmp_path / "fixed.mcap")
    est = _estimates(tmp_path / "fixed.mcap")
    for node in ("m1", "m2"):
        t = rec.imu[node].t_ns
        assert (t[-1] - t[0]) * 1e-9 >= 4.0 - 1.5, node  # 4 s of samples before the kill, less about a second
    assert len(est) and (est[-1, 0] - rec.start_time_ns - rec.imu["m1"].t_ns[0]) * 1e-9 >= 4.0 - 2.5


def test_a_port_in_use_is_one_line_and_exit_2(tmp_path, capsys):
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    taken.bind(("127.0.0.1", 0))
    try:
        port = taken.getsockname()[1]
        (free,) = free_udp_ports(1)
        code = main(["twin", "-o", str(tmp_path / "t.mcap"), "--node", f"m1={port}", "--node", f"m2={free}"])
    finally:
        taken.close()
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("pendsim: error:") and "\n" not in err and str(port) in err
    assert list(tmp_path.iterdir()) == []


def _live_twin(tmp_path, emulator: list[str]) -> Pendsim:
    """A live twin (a real process, writing live.mcap in tmp_path) fed by the emulator with these
    options over loopback UDP until the emulator ends; then SIGINT, and it must end cleanly."""
    p1, p2 = free_udp_ports(2)
    ports = ["--node", f"m1={p1}", "--node", f"m2={p2}"]
    twin = Pendsim(["twin", "-o", "live.mcap", "--duration-s", "60", *ports], cwd=tmp_path)
    try:
        twin.wait_for("twin: listening")
        sender = _emulate([*emulator, *ports])
        sender.join()
        twin.signal(signal.SIGINT)
        assert twin.finish() == 0, twin.err
    finally:
        twin.kill()
    return twin


def test_damping_and_dry_friction_sent_over_udp_from_imperfect_nodes_are_alarmed_on_their_hinges(tmp_path):
    """Nodes with a heading, glued on 2 deg askew, their fused orientation wandering 0.2 deg, 2 %
    of their packets lost and 1 ms of jitter; M1's damping doubles 5 s after the release and M2's
    hinge gains 2e-4 N m of dry friction at 14 s (``pendsim nodes --fault``). The live twin names
    each on its own hinge, by about its size, within 10 s, and nothing else."""
    imperfect = ["--heading-deg", "40", "--mount-misalignment-deg", "2", "--fusion-error-deg", "0.2",
                 "--loss", "0.02", "--jitter-ms", "1"]  # fmt: skip
    faults = ["--fault", "damping:m1*2@5", "--fault", "friction:m2=2e-4@14"]
    _live_twin(tmp_path, ["--duration-s", "26", "--hold-s", "1", "--seed", "4", *imperfect, *faults])
    meta = _metadata(tmp_path / "live.mcap")[twin_topics.TWIN_RESULT_METADATA]
    alarms = {a["parameter"]: a for a in json.loads(meta["alarms"])}
    assert set(alarms) == {"b1_n_m_s", "friction2_n_m"}, alarms
    damping, friction = alarms["b1_n_m_s"], alarms["friction2_n_m"]
    assert damping["value"] / damping["reference"] == pytest.approx(2.0, abs=0.2)
    assert friction["value"] - friction["reference"] == pytest.approx(2e-4, abs=0.6e-4)
    # the faults 9 s apart; each alarm within 10 s of its fault (the release about 1 s after the start)
    assert friction["t_s"] - damping["t_s"] == pytest.approx(9.0, abs=4.0)


def test_scripted_faults_sent_over_udp_are_alarmed_on_the_right_parameter_within_seconds(tmp_path, capsys):
    """The emulated rig's springs weaken by 5 % 6 s after the release, M2's node turns by 3 deg on
    its mount at 12 s and M1's clock jumps by 0.5 s at 16 s (``pendsim nodes --fault``); the live
    twin names each, on its own parameter or node, and nothing else."""
    faults = ["--fault", "stiffness:-5%@6", "--fault", "mount:m2=3deg@12", "--fault", "clock:m1=+0.5@16"]
    began_s = time.time()
    twin = _live_twin(tmp_path, ["--duration-s", "20", "--hold-s", "1", "--seed", "3", *faults])
    ended_s = time.time()
    meta = _metadata(tmp_path / "live.mcap")[twin_topics.TWIN_RESULT_METADATA]
    alarms = {a["parameter"]: a for a in json.loads(meta["alarms"])}
    assert set(alarms) == {"coupling_sin_n_m", "offset_m2_rad"}, alarms
    said = [line for line in twin.err if line.startswith("twin: alarm: ")]  # said while running (the summary: stdout)
    assert len(said) == 2 and "coupling_sin_n_m" in said[0] and "offset_m2_rad" in said[1], twin.err
    for line in said:  # the alarm's time of day (UTC): while the twin ran (its seconds match no one's log)
        of_day = sum(int(v) * k for v, k in zip(line.split(" UTC)")[-2][-8:].split(":"), (3600, 60, 1), strict=True))
        assert (of_day - math.floor(began_s)) % 86400 <= ended_s - began_s + 1, (line, began_s, ended_s)
    assert any(" samples m1 " in line and " alarms " in line for line in twin.err)  # the status line, every 10 s
    # the session's events said as they happen (the clock jump once: said when seen)
    starts = ("twin: the rig is swinging: tracking (at ", "twin: the rig was released: tracking (at ")
    tracking = [line for line in twin.err if line.startswith(starts)]
    assert len(tracking) == 1 and tracking[0].endswith(" UTC)"), twin.err
    assert sum("its clock jumped" in line for line in twin.err) == 1, twin.err
    assert any(line.startswith("twin: m2 angle jumped by +3.0") for line in twin.err), twin.err
    springs, mount = alarms["coupling_sin_n_m"], alarms["offset_m2_rad"]
    assert springs["value"] / springs["reference"] - 1 == pytest.approx(-0.05, abs=0.01)
    assert math.degrees(mount["value"] - mount["reference"]) == pytest.approx(3.0, abs=0.2)
    # each raised within 10 s of its fault (the twin's clock: the release about 1 s after its start)
    assert mount["t_s"] - springs["t_s"] == pytest.approx(6.0, abs=4.0)
    assert mount["since_s"] <= mount["t_s"] - 3.0
    events = [what for _, what in json.loads(meta["events"])]
    jumps = [float(e.split("by ")[1].split(" s")[0]) for e in events if e.startswith("m1: its clock jumped by ")]
    assert len(jumps) == 1 and jumps[0] == pytest.approx(0.5, abs=0.02)  # the packets' own jitter aside
    assert any(e.startswith("m2 angle jumped by +3.0") for e in events)
    p50, p99 = json.loads(meta["latency_ms"])
    assert 0 < p50 <= p99  # measured per sample, from its arrival to its estimate
    assert any("latency, sample arrival -> estimate" in line for line in twin.out)
    # a replay of the twin's own recording gives its live estimates again, bit for bit
    live = _estimates(tmp_path / "live.mcap")
    assert len(live) > 2000
    replay = ["twin", "--replay", str(tmp_path / "live.mcap"), "--speed", "0", "-o", str(tmp_path / "again.mcap")]
    capsys.readouterr()
    assert main(replay) == 0
    # and says the same alarms and events, at the same times of day (a clock jump: live only, when seen)
    replay_said = capsys.readouterr()
    narrated = ("twin: alarm: ", *starts, "twin: m2 angle jumped", "twin: health checks held")

    def said_lines(lines: list[str]) -> list[str]:
        return [line for line in lines if line.startswith(narrated)]

    assert said_lines((replay_said.out + replay_said.err).splitlines()) == said_lines(twin.err), replay_said
    again = _estimates(tmp_path / "again.mcap")
    assert again.shape == live.shape and np.array_equal(again, live)
    replayed = _metadata(tmp_path / "again.mcap")[twin_topics.TWIN_RESULT_METADATA]
    assert [a["parameter"] for a in json.loads(replayed["alarms"])] == [
        a["parameter"] for a in json.loads(meta["alarms"])
    ]
    # the same times of day: the replay's clock starts where the recording's did
    assert [a["text"] for a in json.loads(replayed["alarms"])] == [a["text"] for a in json.loads(meta["alarms"])]
