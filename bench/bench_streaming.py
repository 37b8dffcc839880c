"""Memory of streaming record and streaming reads, each in a fresh process (peak RSS).

Run: python bench/bench_streaming.py [--hours 1] [--read-hours 6]

1. ``record``: peak RSS of a 2 min recording and of an --hours one (default 1 h); the ratio says
   whether memory grows with the duration (it should not: the run is simulated and written in
   30 s blocks).
2. ``read_recording``: a --read-hours static recording (default 6 h, the paper's noise test) read
   back into arrays: wall time, peak RSS, the bytes of the decoded arrays, and their ratio (the
   reader decodes chunk by chunk into preallocated per-field arrays, never holding all payloads).
Baselines in the same run: the RSS of a process that only imports pendsim (what every command
pays before doing anything).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RECORD = """
import sys, time
from pendsim_bridge.run.record import RecordSpec, record
start = time.perf_counter()
model = sys.argv[3]
record(RecordSpec(duration_s=float(sys.argv[1]), model=model), sys.argv[2], start_time_ns=0)
print(time.perf_counter() - start, int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0]))
"""
READ = """
import sys, time
import numpy as np
from pendsim_bridge.io.recording import read_recording
start = time.perf_counter()
rec = read_recording(sys.argv[1])
took = time.perf_counter() - start
arrays = 0
for topic in rec.imu.values():
    for value in vars(topic).values():
        if isinstance(value, np.ndarray) and value.strides[0] != 0:
            arrays += value.nbytes
for store in (rec.linear_accel_m_s2, rec.gravity_m_s2, rec.calibration):
    arrays += sum(t.nbytes + v.nbytes for t, v in store.values())
print(took, int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0]), arrays, len(rec.imu["m1"].t_ns))
"""
IMPORT_ONLY = """
import pendsim_bridge.io.recording, pendsim_bridge.run.record
print(0, int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0]))
"""


def run(script: str, *args: str) -> list[float]:
    done = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, check=True)
    return [float(x) for x in done.stdout.split()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--read-hours", type=float, default=6.0)
    args = parser.parse_args()
    base_mb = run(IMPORT_ONLY)[1] / 1024
    print(f"baseline: importing pendsim's record and recording modules: {base_mb:.0f} MB peak RSS")
    with tempfile.TemporaryDirectory() as tmp:
        rows = []
        for seconds in (120.0, args.hours * 3600):
            path = Path(tmp) / f"r{seconds:g}.mcap"
            took, rss = run(RECORD, str(seconds), str(path), "planar")
            rows.append((seconds, took, rss / 1024, path.stat().st_size / 1e6))
            path.unlink()
        print(f"{'record (planar, MuJoCo)':26} {'wall s':>8} {'peak MB':>8} {'file MB':>8}")
        for seconds, took, rss_mb, size in rows:
            print(f"{seconds / 60:10.0f} min {'':14} {took:8.1f} {rss_mb:8.0f} {size:8.1f}")
        ratio = rows[1][2] / rows[0][2]
        longer = rows[1][0] / rows[0][0]
        print(f"peak memory {args.hours * 60:.0f} min / 2 min: {ratio:.2f}x for {longer:.0f}x the duration")

        path = Path(tmp) / "static.mcap"
        start = time.perf_counter()
        run(RECORD, str(args.read_hours * 3600), str(path), "static")
        write_s = time.perf_counter() - start
        took, rss, arrays, samples = run(READ, str(path))
        rss_mb, arrays_mb = rss / 1024, arrays / 1e6
        print(
            f"static {args.read_hours:g} h: written in {write_s:.1f} s ({path.stat().st_size / 1e6:.0f} MB, "
            f"{int(samples):,} samples per node)"
        )
        print(
            f"read_recording: {took:.1f} s, peak RSS {rss_mb:.0f} MB ({rss_mb - base_mb:.0f} MB above the import "
            f"baseline) for {arrays_mb:.0f} MB of decoded arrays: {(rss_mb - base_mb) / arrays_mb:.2f}x"
        )


if __name__ == "__main__":
    main()
