"""Time to turn a recording into a Rerun .rrd with pendsim view (issue 6 targets: a 120 s
recording under 1 s, a 1 h one under 20 s). Recordings are made first (not timed).

Run: python bench/bench_view.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pendsim_bridge.cli import main as cli
from pendsim_bridge.report.rerun_view import view_recording


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for duration, target in ((120, 1.0), (3600, 20.0)):
            path = Path(tmp) / f"run_{duration}.mcap"
            cli(["record", "-o", str(path), "--duration-s", str(duration), "--hold-s", "1"])
            times = []
            for k in range(args.repeat):
                start = time.perf_counter()
                view_recording(path, Path(tmp) / f"run_{duration}_{k}.rrd")
                times.append(time.perf_counter() - start)
            size = (Path(tmp) / f"run_{duration}_0.rrd").stat().st_size / 1e6
            runs = ", ".join(f"{t:.2f}" for t in times)
            best = min(times)
            what = f"{duration:5d} s recording -> .rrd"
            print(f"{what}: best {best:.2f} s (runs {runs}; target < {target:g} s), {size:.1f} MB")


if __name__ == "__main__":
    main()
