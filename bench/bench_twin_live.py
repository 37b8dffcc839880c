"""The live twin over loopback UDP: the emulated nodes (``pendsim nodes``, all of the BNO055
model's default imperfections) sending to ``pendsim twin``, both real processes. Measured: the
latency from a sample's arrival (the kernel's stamp) to its estimate, median and 99th percentile,
as the twin records it; the twin process's CPU time per second of data, without and with the live
views (Rerun to an .rrd file, Foxglove serving), against the issue's 20 % of one core; the load.

And what the machine charges a loop that wakes up: a live twin works for a fraction of a
millisecond every 6 ms (a packet), and each time finds its code and data gone from the caches where
other work ran meanwhile. Measured here as the wall time of one small fixed call (numpy's sum of
16 KB) back to back and after 6 ms of a spin loop (no sleep, so no idle state: only time passing),
medians of 300. On 2026-11-27's shared 2-core machine: 3.8 us against 107 us (30 times); the
twin's own sample step there costs 0.25-0.3 ms back to back and 0.7 ms at the recording's pace.

Run: python bench/bench_twin_live.py [--seconds 60]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from mcap.reader import make_reader

PENDSIM = [sys.executable, "-m", "pendsim_bridge.cli"]


def free_udp_ports(count: int) -> list[int]:
    sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(count)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def one_run(folder: Path, seconds: float, views: list[str]) -> dict[str, float]:
    p1, p2 = free_udp_ports(2)
    ports = ["--node", f"m1={p1}", "--node", f"m2={p2}"]
    out = folder / f"twin{len(views)}.mcap"
    twin = subprocess.Popen(
        [*PENDSIM, "twin", "-o", str(out), "--force", "--duration-s", str(seconds + 6), *ports, *views],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert twin.stderr is not None
    for line in twin.stderr:  # the twin's start-up (imports) is not its running cost
        if line.startswith("twin: listening"):
            break
    cpu_before = cpu_s(twin.pid)
    subprocess.run([*PENDSIM, "nodes", "--duration-s", str(seconds), "--hold-s", "2", *ports],
                           capture_output=True, text=True, check=True)  # fmt: skip
    cpu_after = cpu_s(twin.pid)
    _, err = twin.communicate(timeout=120)
    if twin.returncode != 0:
        raise SystemExit(f"twin failed: {err}")
    with open(out, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["pendsim/twin_result"]
    p50, p99 = json.loads(meta["latency_ms"])
    return {"p50_ms": p50, "p99_ms": p99, "cpu_share": (cpu_after - cpu_before) / seconds}


def wake_penalty_us(gap_s: float = 0.006, calls: int = 300) -> tuple[float, float]:
    """Median wall time (us) of numpy's sum of 16 KB back to back and after ``gap_s`` of a spin."""
    import statistics
    import time

    import numpy as np

    values = np.random.default_rng(1).random(2048)
    medians = []
    for gap in (0.0, gap_s):
        spent = []
        for _ in range(calls):
            end = time.perf_counter() + gap
            while time.perf_counter() < end:
                pass
            t0 = time.perf_counter_ns()
            values.sum()
            spent.append(time.perf_counter_ns() - t0)
        medians.append(statistics.median(spent) / 1e3)
    return medians[0], medians[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rows = [
            ("twin alone", one_run(folder, args.seconds, [])),
            ("with Rerun (.rrd) and Foxglove", one_run(folder, args.seconds, ["--rerun", str(folder / "t.rrd"),
                                                                             "--foxglove", "18765"])),
        ]  # fmt: skip
    warm_us, woken_us = wake_penalty_us()
    print(f"load average {os.getloadavg()[0]:.1f}; {args.seconds:g} s of two nodes at 80 Hz over loopback UDP")
    print(f"the machine's wake-up penalty: numpy's sum of 16 KB {warm_us:.1f} us back to back, {woken_us:.1f} us "
          f"after 6 ms of other work ({woken_us / warm_us:.0f} times)")  # fmt: skip
    print(f"{'':34} {'latency p50':>12} {'p99':>8} {'CPU of one core':>16}")
    for name, r in rows:
        print(f"{name:34} {r['p50_ms']:10.1f} ms {r['p99_ms']:5.1f} ms {100 * r['cpu_share']:14.1f} %")


if __name__ == "__main__":
    main()
