"""Compile pendsim's numba kernels into the cache before the suite runs (``conftest``), in two
processes at once, each through the product's own commands: on a fresh clone (a cold cache, as in
CI) the test workers and the commands the tests start would otherwise each compile the same
kernels at the same moment (2 minutes of the suite's 9 on 2 cores, measured 2026-11-27). On a warm
cache each part only loads them (a few seconds).

Run: python tests/warm_kernels.py PART FOLDER (PART: engine or measure)
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path

from pendsim_bridge.cli import main

DRIVE = ["--set", "torque_m1_amplitude_n_m=0.003", "--set", "torque_m1_frequency_hz=0.87"]
PARTS = {
    "engine": [
        ["simulate", "--engine", "fast", "--duration-s", "2"],
        ["simulate", "--engine", "fast", "--duration-s", "2", "--torque1-n-m", "sine:0.003,0.87"],
        ["sweep", "--vary", "phi1_deg=10:60:3", "--duration-s", "4", "--no-plots", "-o", "{out}/sweep"],
        ["sweep", "--random", "40", "--vary", "phi1_deg=10:60", "--duration-s", "4", "--no-plots", "-o", "{out}/big"],
        ["sweep", "--random", "40", "--vary", "phi1_deg=10:60", *DRIVE, "--duration-s", "4", "--no-plots",
         "-o", "{out}/driven"],
    ],
    "measure": [
        ["record", "-o", "{out}/run.mcap", "--duration-s", "8"],
        ["validate", "{out}/run.mcap", "-o", "{out}/validate"],
        ["twin", "--replay", "{out}/run.mcap", "--speed", "0", "-o", "{out}/twin.mcap"],
        ["record", "--static", "-o", "{out}/static.mcap", "--duration-s", "20"],
        ["allan", "{out}/static.mcap", "--no-plots"],
    ],
}  # fmt: skip


def run(part: str, folder: str) -> int:
    failed = 0
    for command in PARTS[part]:
        args = [a.format(out=folder) for a in command]
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            try:
                code = main(args)
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else 1
        if code:
            print(f"warm_kernels: pendsim {' '.join(args)} exited {code}", file=sys.stderr)
            failed += 1
    return failed


if __name__ == "__main__":
    Path(sys.argv[2]).mkdir(parents=True, exist_ok=True)
    sys.exit(run(sys.argv[1], sys.argv[2]))
