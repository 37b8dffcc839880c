"""Acquisition under load, on loopback, with real subprocesses (``pendsim nodes`` -> ``pendsim acquire``).

1. **Soak**: two nodes at 80 Hz for ``--minutes`` (default 10) in real time: packets sent and
   received, loss, the drift and jitter acquire reports, and the CPU acquire used (user + system,
   from the kernel's accounting of the child), as a share of one core and per packet against a
   baseline measured in the same run: a bare receiver (recv and count, nothing else) on the same
   kind of stream for ``--baseline-s``.
2. **Burst**: two nodes at 10 000 Hz each (20 000 packets/s) for ``--burst-s`` (default 10):
   received versus sent, and that every sample received is in the file exactly once.

    python bench/bench_acquire.py                       # both, about 11 minutes
    python bench/bench_acquire.py --minutes 1 --burst-s 5
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PENDSIM = [sys.executable, "-m", "pendsim_bridge.cli"]


def free_ports(count: int) -> list[int]:
    sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(count)]
    for s in sockets:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in sockets]
    for s in sockets:
        s.close()
    return ports


def wait_listening(process: subprocess.Popen[str], timeout_s: float = 120.0) -> None:
    assert process.stderr is not None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = process.stderr.readline()
        if "listening:" in line:
            return
        if not line and process.poll() is not None:
            break
    raise RuntimeError("acquire did not start")


def cpu_of_child(process: subprocess.Popen[str]) -> float:
    """Wait for the child and return its user + system CPU seconds."""
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_utime + usage.ru_stime


def run_pair(folder: Path, rate_hz: float, duration_s: float, extra_acquire: list[str]) -> dict:
    """nodes -> acquire; returns the counters, CPU and the emulator's log."""
    from pendsim_bridge.acquire.emulator import read_log
    from pendsim_bridge.io.mcap.reader import read_mcap

    p1, p2 = free_ports(2)
    ports = ["--node", f"m1={p1}", "--node", f"m2={p2}"]
    out = folder / f"run_{rate_hz:g}.mcap"
    log = folder / f"sent_{rate_hz:g}.jsonl"
    acquire = subprocess.Popen(
        [*PENDSIM, "acquire", "-o", str(out), "--rate-hz", str(rate_hz), *ports, *extra_acquire],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    wait_listening(acquire)
    hold = min(2.0, duration_s / 4)
    nodes = subprocess.run(
        [*PENDSIM, "nodes", "--rate-hz", str(rate_hz), "--duration-s", str(duration_s), "--hold-s", str(hold),
         "--log", str(log), *ports],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    time.sleep(1.0)
    acquire.send_signal(signal.SIGTERM)
    cpu = cpu_of_child(acquire)
    summary = acquire.stdout.read() if acquire.stdout else ""
    assert acquire.returncode == 0, (acquire.returncode, acquire.stderr.read() if acquire.stderr else "")
    _, rows = read_log(log)
    contents = read_mcap(out)
    counts = {ch.topic: len(contents.messages.get(cid, [])) for cid, ch in contents.channels.items()}
    return {"summary": summary, "nodes_out": nodes.stdout, "rows": rows, "cpu_s": cpu, "counts": counts}


def bare_receiver_cpu(rate_hz: float, duration_s: float) -> tuple[float, int]:
    """CPU seconds and packets of a receiver that only reads and counts, fed by the emulator."""
    p1, p2 = free_ports(2)
    code = (
        "import selectors, socket, sys, time\n"
        "sel = selectors.DefaultSelector(); n = 0\n"
        f"for p in ({p1}, {p2}):\n"
        "    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(('127.0.0.1', p)); s.setblocking(False)\n"
        "    sel.register(s, selectors.EVENT_READ)\n"
        "print('listening:', file=sys.stderr, flush=True)\n"
        f"end = time.monotonic() + {duration_s + 60}\n"
        "last = None\n"
        "while time.monotonic() < end:\n"
        "    got = sel.select(0.05)\n"
        "    for key, _ in got:\n"
        "        while True:\n"
        "            try: key.fileobj.recv(65535); n += 1; last = time.monotonic()\n"
        "            except BlockingIOError: break\n"
        "    if last and time.monotonic() - last > 1.5: break\n"
        "print(n)\n"
    )
    receiver = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_listening(receiver)
    subprocess.run(
        [*PENDSIM, "nodes", "--rate-hz", str(rate_hz), "--duration-s", str(duration_s), "--hold-s", "1",
         "--node", f"m1={p1}", "--node", f"m2={p2}"],
        capture_output=True, check=True,
    )  # fmt: skip
    cpu = cpu_of_child(receiver)
    packets = int(receiver.stdout.read().strip()) if receiver.stdout else 0
    return cpu, packets


def soak(minutes: float, baseline_s: float, folder: Path) -> None:
    duration = minutes * 60
    print(f"soak: two nodes at 80 Hz for {duration:g} s in real time, loopback")
    base_cpu, base_packets = bare_receiver_cpu(80.0, baseline_s)
    result = run_pair(folder, 80.0, duration, [])
    sent = sum(1 for r in result["rows"] if r["sent"])
    received_in_file = result["counts"].get("/imu/m1", 0) + result["counts"].get("/imu/m2", 0)
    per_packet = result["cpu_s"] / max(sent, 1)
    base_per_packet = base_cpu / max(base_packets, 1)
    print(result["summary"].rstrip())
    print(f"  sent {sent} packets, {received_in_file} samples in the file, loss on loopback {sent - received_in_file}")
    print(
        f"  acquire CPU {result['cpu_s']:.2f} s over {duration:g} s = {100 * result['cpu_s'] / duration:.2f} % of one "
        f"core; {per_packet * 1e6:.1f} us per packet"
    )
    print(
        f"  baseline (bare recv loop, {baseline_s:g} s): {base_per_packet * 1e6:.1f} us per packet; "
        f"acquire / baseline = {per_packet / base_per_packet:.1f}x"
    )


def burst(seconds: float, folder: Path) -> None:
    print(f"burst: two nodes at 10000 Hz (20000 packets/s) for {seconds:g} s, loopback")
    result = run_pair(folder, 10_000.0, seconds, [])
    rows = result["rows"]
    for node in ("m1", "m2"):
        sent = [r for r in rows if r["node"] == node and r["sent"]]
        distinct = len({r["seq"] for r in sent})
        line = next(x for x in result["summary"].splitlines() if x.strip().startswith(node))
        received, written = int(line.split()[2]), int(line.split()[3])
        in_file = result["counts"].get(f"/imu/{node}", 0)
        print(
            f"  {node}: sent {len(sent)}, received {received} ({100 * received / len(sent):.2f} %), "
            f"written {written}, in the file {in_file} (every received sample in the file: {in_file == written}, "
            f"distinct sent {distinct})"
        )
    done = next(x for x in result["nodes_out"].splitlines() if x.startswith(("done", "stopped")))
    print(f"  emulator: {done} (the sender's own lateness shows in acquire's jitter and drift)")
    print(result["summary"].rstrip())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="soak length (default 10)")
    parser.add_argument("--baseline-s", type=float, default=30.0, help="bare receiver baseline length (default 30)")
    parser.add_argument("--burst-s", type=float, default=10.0, help="burst length (default 10)")
    parser.add_argument("--skip-soak", action="store_true")
    parser.add_argument("--skip-burst", action="store_true")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; {time.strftime('%Y-%m-%d %H:%M')}")
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_burst:
            burst(args.burst_s, Path(tmp))
        if not args.skip_soak:
            soak(args.minutes, args.baseline_s, Path(tmp))


if __name__ == "__main__":
    main()
