"""CPU time and peak memory of calibration (issue 22 targets: one 120 s recording in at most
10 s CPU; a 1 h recording in at most 60 s CPU and 500 MB), with ``identify`` on the same
recordings as the baseline measured in the same run (the ratio is what stays comparable across
machines). Each measurement runs in a fresh interpreter: its CPU time starts after the imports,
its peak memory is the process's own high-water mark (VmHWM, not ru_maxrss, which a forked
child inherits from its parent). The recordings (a rig 3 % stiffer in c1, 2 % heavier in J1,
1 % shorter in OC2 than the paper's) are made first, not timed. What is timed is what
``pendsim calibrate --no-checks`` runs: reading, alignment, the fit, the design of the next
experiment; the validations before and after come on top (``--checks`` times them too).

Run: python bench/bench_calibrate.py [--checks] [--no-1h]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from pendsim_bridge.cli import main as cli

CHILD = r"""
import json, sys, time
from pendsim_bridge.run.calibrate import calibrate_recordings
from pendsim_bridge.run.validate import identify
from pendsim_mj.rig.params import RigParams
path, which, checks = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
start = time.process_time()
if which == "calibrate":
    report = calibrate_recordings([path], RigParams(), checks=checks)
    rms = report.calibration.residual_rms_sigma
else:
    rms = identify(path, overrides={"c1_n_m": 6.173, "j1_kg_m2": 0.02592, "oc2_m": 0.326}).fit.residual_rms_sigma
cpu = time.process_time() - start
hwm = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM"))
print(json.dumps({"cpu_s": cpu, "peak_mb": hwm / 1024, "rms": rms}))
"""
RIG = {"c1_n_m": 6.35819, "j1_kg_m2": 0.0264384, "oc2_m": 0.32274}


def measure(path: Path, which: str, checks: bool) -> dict:
    args = [sys.executable, "-c", CHILD, str(path), which, "1" if checks else "0"]
    out = subprocess.run(args, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checks", action="store_true", help="time the validations before and after too")
    parser.add_argument("--no-1h", action="store_true", help="only the 120 s recording")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rig = Path(tmp) / "rig.json"
        rig.write_text(json.dumps(RIG))
        for duration in (120,) if args.no_1h else (120, 3600):
            path = Path(tmp) / f"run_{duration}.mcap"
            cli(["record", "-o", str(path), "--duration-s", str(duration), "--params-file", str(rig)])
            base = measure(path, "identify", False)
            cal = measure(path, "calibrate", args.checks)
            target = "10 s CPU" if duration == 120 else "60 s CPU, 500 MB"
            print(
                f"{duration:5d} s  identify (paper's rig: a misfit) CPU {base['cpu_s']:6.2f} s  "
                f"peak {base['peak_mb']:5.0f} MB  rms {base['rms']:.1f} sigma"
            )
            print(
                f"{duration:5d} s  calibrate{' (with checks)' if args.checks else ''}  CPU {cal['cpu_s']:6.2f} s "
                f"({cal['cpu_s'] / base['cpu_s']:.2f} x identify)  peak {cal['peak_mb']:5.0f} MB  "
                f"rms {cal['rms']:.2f} sigma  (target {target})"
            )


if __name__ == "__main__":
    main()
