"""The closed loop over UDP on loopback: its latency and jitter, measured from what the code recorded.

``pendsim nodes --motor`` (a real subprocess: the rig with motors, both nodes, the actuator) and
``run_rig_loop`` with LQR in this process, from a 30 deg release, for ``--seconds`` after a 1 s
hold; then the same with ``--busy`` busy CPU loops beside them (default 2). Each run reports:

- the loop's round trip: command sent -> the actuator's status for it back (median, p99);
- sample -> command: the older of the two nodes' newest samples taken -> the command sent;
- the loop's jitter: each tick's start after its scheduled instant; and its compute per tick;
- the emulator's side: node packets sent after their instants, commands read after their
  arrival (the kernel's stamp), commands to zero-torque events;
- the decay (to 1/e) of both modes over UDP, and the share of CPU time a hypervisor took (steal);

against a baseline measured in the same run: a bare UDP echo round trip on loopback (a second
process that sends each datagram back, 100 a second), the floor any loop over these sockets has.
``--no-realtime`` runs without real-time scheduling (what an unprivileged user gets).

    python bench/bench_control_udp.py                  # about 1 minute
    python bench/bench_control_udp.py --seconds 30 --busy 2 --no-realtime
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pendsim_bridge.acquire.ports import NodeSpec
from pendsim_bridge.acquire.udp_loop.rig_loop import run_rig_loop
from pendsim_mj.control import LQR
from pendsim_mj.control.linear import decay_time_s, linearise
from pendsim_mj.rig.params import DEFAULT_PARAMS

PENDSIM = [sys.executable, "-m", "pendsim_bridge.cli"]
ECHO = """
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
while True:
    data, address = s.recvfrom(64)
    if data == b"end": break
    s.sendto(data, address)
"""


def free_ports(count: int) -> list[int]:
    sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(count)]
    for s in sockets:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in sockets]
    for s in sockets:
        s.close()
    return ports


def p50_p99_ms(values_s) -> str:
    v = np.asarray(values_s, dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return "-"
    p50, p99 = np.percentile(v, [50, 99]) * 1e3
    return f"{p50:7.3f} / {p99:7.3f}"


def echo_baseline(count: int = 500) -> np.ndarray:
    """Round trips (s) of ``count`` datagrams to an echo process, one every 10 ms."""
    echo = subprocess.Popen([sys.executable, "-c", ECHO], stdout=subprocess.PIPE, text=True)
    try:
        assert echo.stdout is not None
        port = int(echo.stdout.readline())
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.connect(("127.0.0.1", port))
        sock.settimeout(1.0)
        out = []
        for i in range(count):
            t0 = time.monotonic_ns()
            sock.send(i.to_bytes(4, "little"))
            sock.recv(64)
            out.append((time.monotonic_ns() - t0) * 1e-9)
            time.sleep(0.01)
        sock.send(b"end")
        sock.close()
        return np.array(out)
    finally:
        echo.wait(timeout=10)


def run_once(folder: Path, seconds: float, realtime: bool) -> dict[str, object]:
    p1, p2, pa = free_ports(3)
    log = folder / f"rig_{time.monotonic_ns()}.jsonl"
    rig = subprocess.Popen(
        [*PENDSIM, "nodes", "--motor", "--node", f"m1={p1}", "--node", f"m2={p2}", "--actuator-port", str(pa),
         "--duration-s", str(seconds + 1.0), "--hold-s", "1", "--log", str(log)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert rig.stdout is not None
        while "commands on" not in (line := rig.stdout.readline()):
            if not line and rig.poll() is not None:
                raise RuntimeError(f"the rig did not start: {rig.stderr.read() if rig.stderr else ''}")
        result = run_rig_loop(
            LQR(), nodes=(NodeSpec("m1", p1), NodeSpec("m2", p2)), actuator=("127.0.0.1", pa), duration_s=seconds + 30,
            should_stop=lambda: rig.poll() is not None, realtime_priority=realtime, say=lambda line: None,
        )  # fmt: skip
        rig.communicate(timeout=60)
    finally:
        if rig.poll() is None:
            rig.kill()
            rig.wait()
    lines = log.read_text().splitlines()
    header, rows = json.loads(lines[0]), [json.loads(line) for line in lines[1:]]
    steps = [r for r in rows if r["kind"] == "step"]
    t = np.array([r["t_s"] for r in steps]) - header["hold_s"]
    x = np.array([[r["phi1_rad"], r["phi2_rad"], r["omega1_rad_s"], r["omega2_rad_s"]] for r in steps])
    amplitudes = linearise(DEFAULT_PARAMS).mode_amplitudes_rad(x[t >= 0])
    decay = [decay_time_s(t[t >= 0], amplitudes[:, i]) for i in range(2)]
    sent = [r["sent_s"] - r["t_s"] for r in rows if r["kind"] == "sample" and r.get("sent")]
    read = [r["read_s"] - r["arrival_s"] for r in rows if r["kind"] == "command"]
    safe = {}
    for r in rows:
        if r["kind"] == "safe" and r["reason"] not in ("waiting", "shutdown"):
            safe[r["reason"]] = safe.get(r["reason"], 0) + 1
    running = np.array([reason == "none" for reason in result.stop_reason])
    oldest = np.max(result.age_s, axis=1) + (result.sent_s - result.tick_s)
    return {
        "round_trip": result.round_trip_s,
        "sample_to_command": oldest[running],
        "tick_lateness": result.tick_s - result.t_s,
        "compute": (result.sent_s - result.tick_s)[running],
        "send_lateness": np.array(sent),
        "read_lateness": np.array(read),
        "safe": safe,
        "skipped": result.skipped_ticks,
        "decay": decay,
        "realtime": realtime and not any("not permitted" in text for _, text in result.events),
    }


def cpu_ticks() -> tuple[int, int]:
    """(steal, total) jiffies of all CPUs since boot (Linux /proc/stat; (0, 0) elsewhere): the time
    a hypervisor ran other guests on this machine's virtual CPUs, which no priority inside it beats."""
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    except (OSError, ValueError):
        return 0, 0
    return (fields[7] if len(fields) > 7 else 0), sum(fields)


def busy_loops(count: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="controlled seconds per run (default 20)")
    parser.add_argument("--busy", type=int, default=2, help="busy CPU loops in the second run (default 2)")
    parser.add_argument("--no-realtime", action="store_true", help="normal scheduling priority")
    args = parser.parse_args()
    echo = echo_baseline()
    print(f"baseline: bare UDP echo round trip on loopback, median / p99 ms: {p50_p99_ms(echo)}")
    with tempfile.TemporaryDirectory() as tmp:
        for busy in (0, args.busy):
            loops = busy_loops(busy)
            steal0, total0 = cpu_ticks()
            try:
                r = run_once(Path(tmp), args.seconds, not args.no_realtime)
            finally:
                steal1, total1 = cpu_ticks()
                for p in loops:
                    p.kill()
                    p.wait()
            median_echo = float(np.median(echo))
            ratio = np.nanmedian(r["round_trip"]) / median_echo if median_echo > 0 else math.nan
            print(f"\n{busy} busy loops, real-time scheduling {'on' if r['realtime'] else 'off'} (median / p99 ms):")
            print(f"  round trip, command -> status   {p50_p99_ms(r['round_trip'])}   ({ratio:.1f}x the echo)")
            print(f"  sample taken -> command sent    {p50_p99_ms(r['sample_to_command'])}")
            print(f"  tick lateness (loop jitter)     {p50_p99_ms(r['tick_lateness'])}")
            print(f"  compute per tick                {p50_p99_ms(r['compute'])}")
            print(f"  node packet send lateness       {p50_p99_ms(r['send_lateness'])}")
            print(f"  command read after arrival      {p50_p99_ms(r['read_lateness'])}")
            print(f"  ticks skipped {r['skipped']}; zero-torque events {r['safe'] or 'none'}")
            steal = (steal1 - steal0) / (total1 - total0) if total1 > total0 else math.nan
            print(f"  CPU time stolen by the hypervisor during the run: {100 * steal:.1f} %")
            print(f"  decay to 1/e over UDP: mode 1 {r['decay'][0]:.3f} s, mode 2 {r['decay'][1]:.3f} s")


if __name__ == "__main__":
    main()
