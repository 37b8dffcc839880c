"""CPU time and peak memory of damping identification (issue 16 target: identify on a 1 h
recording at most 15 s CPU and 500 MB peak): the planar fit that ``pendsim identify`` runs now
against the previous mujoco.sysid fit of b1, b2, on 120 s and 1 h recordings, in one run.
Each measurement runs in a fresh interpreter (its peak RSS includes the imports, its CPU time
starts after them); the recordings are made first (not timed). Old path at 1 h: minutes and over 1 GB (skip it with
--no-old-1h).

Run: python bench/bench_identify.py [--no-old-1h]
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
import json, resource, sys, time
import numpy as np
from pendsim_bridge.io.recording import read_recording
from pendsim_bridge.io.measured import align_recording, recorded_params
from pendsim_bridge.run.validate import identify
from pendsim_mj.estimation.identification import fit_damping
path, which = sys.argv[1], sys.argv[2]
start = time.process_time()
if which == "new":
    fit = identify(path).fit
else:  # the previous path: sysid over MuJoCo rollouts, the release state taken as known
    rec = read_recording(path)
    params = recorded_params(rec)
    run = align_recording(rec, params)
    omega, at = run.both_nodes("omega_rad_s"), run.both_nodes("value_t_s")
    fit = fit_damping(params, run.start.phi_rad, np.clip(at, 0, None), omega,
                      gyro_sigma_rad_s=run.gyro_sigma_rad_s, fusion_rate_hz=None)
cpu = time.process_time() - start
print(json.dumps({"cpu_s": cpu, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "b": fit.b_n_m_s.tolist(), "ci": fit.ci95_n_m_s.tolist()}))
"""


def measure(path: Path, which: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(path), which], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-old-1h", action="store_true", help="skip the sysid path on the 1 h recording")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for duration in (120, 3600):
            path = Path(tmp) / f"run_{duration}.mcap"
            cli(["record", "-o", str(path), "--duration-s", str(duration), "--hold-s", "1"])
            for which in ("old", "new"):
                if which == "old" and duration == 3600 and args.no_old_1h:
                    continue
                r = measure(path, which)
                label = "planar (new)" if which == "new" else "sysid (old)"
                b = ", ".join(f"{v:.5g} +- {c:.2g}" for v, c in zip(r["b"], r["ci"], strict=True))
                target = "  (target <= 15 s, 500 MB)" if which == "new" and duration == 3600 else ""
                print(
                    f"{duration:5d} s  {label:13} CPU {r['cpu_s']:6.2f} s  peak RSS {r['peak_mb']:6.0f} MB"
                    f"  b = {b}{target}"
                )


if __name__ == "__main__":
    main()
