"""Long recordings (issue 16): CPU time, wall time and peak memory of validate, view --save and
allan on 120 s, 1 h and 6 h recordings, against anchors measured in the same run.

Run: python bench/bench_long.py [--durations 120,3600,21600] [--keep DIR] [--cold]

``--cold`` measures first runs: each run gets a fresh, empty ``NUMBA_CACHE_DIR``, so numba
compiles the kernels the command uses inside it, as on the first run after installing (the
targets hold for first runs too, issue 24; ``allan`` 6 h has 8 s wall there).

The recordings are made first with ``pendsim record``'s library (streaming; not timed): a free
planar run (MuJoCo, 1 s held before the release) and a static noise test of each duration. Every
measurement is a process of its own, measured by ``os.wait4`` (its user + system CPU time, wall
time and peak resident memory, imports included), so nothing one leaves behind counts against
the next:

- ``validate --damping recorded`` (the comparison and figures, no damping fit) and ``validate``
  (the default: the fit too);
- ``view --save``;
- ``allan`` with its plots, on the static recording;
- anchors: a bare MuJoCo rollout of the run's duration (``mujoco.rollout``, one member, its
  states only), and the static recording read once plus ``allantools.oadev`` on its 12 axes
  (same tau grid as ``allan``).

Targets (issue 16, "Done when"): validate 1 h <= 30 s CPU and 500 MB (with and without the damping
fit), 6 h < 180 s and 500 MB;
view --save 1 h <= 10 s and 500 MB; allan 6 h <= 5 s wall and 600 MB and faster than the
read-once + allantools anchor. The machine's load average is printed with the table: on a
shared machine wall times are upper bounds; CPU times are what the targets compare.
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CLI = "import sys; from pendsim_bridge.cli import _run; _run()"

ROLLOUT = """
import sys, numpy as np, mujoco
from mujoco import rollout
from pendsim_mj.rig.model import build_model
from pendsim_mj.rig.params import DEFAULT_PARAMS
duration_s = float(sys.argv[1])
model = build_model(DEFAULT_PARAMS, timestep_s=0.01)
data = mujoco.MjData(model)
data.qpos[:2] = (np.pi / 6, 0.0)
mujoco.mj_forward(model, data)
state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
nstep = round(duration_s / 0.01)
block = 6000
for first in range(0, nstep, block):  # in blocks: the anchor's memory is flat too
    states, _ = rollout.rollout(model, data, state[None], nstep=min(block, nstep - first))
    state = states[0, -1]
"""

ALLANTOOLS = """
import sys, numpy as np, allantools
from pendsim_bridge.io.recording import imu_topic, read_recording
from pendsim_mj.allan.deviation import tau_grid
rec = read_recording(sys.argv[1], topics=[imu_topic("m1"), imu_topic("m2")])
for node in ("m1", "m2"):
    topic = rec.imu[node]
    for axes in (topic.accel_m_s2, topic.gyro_rad_s):
        m = tau_grid(len(axes))
        for k in range(3):
            allantools.oadev(axes[:, k], rate=80.0, data_type="freq", taus=m / 80.0)
"""

TARGETS = {  # (measurement, duration_s): (CPU s, wall s, peak MB); None: not a target
    ("validate --damping recorded", 3600): (30.0, None, 500.0),
    ("validate", 3600): (30.0, None, 500.0),
    ("validate --damping recorded", 21600): (180.0, None, 500.0),
    ("view --save", 3600): (10.0, None, 500.0),
    ("allan (plots)", 21600): (None, 5.0, 600.0),
}
COLD_TARGETS = {("allan (plots)", 21600): (None, 8.0, 600.0)}  # --cold: first runs (issue 24); the others as warm


def measure(args: list[str], cold: bool = False) -> tuple[float, float, float, int]:
    """(CPU s, wall s, peak RSS MB, exit code) of one process (``cold``: with an empty numba cache)."""
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache} if cold else None
        return _measure(args, env)


def _measure(args: list[str], env: dict[str, str] | None) -> tuple[float, float, float, int]:
    start = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode:
        print(f"  {' '.join(args[2:])}: exit {proc.returncode}: {err.strip()[-300:]}", file=sys.stderr)
    return usage.ru_utime + usage.ru_stime, wall, usage.ru_maxrss / 1024, proc.returncode


def repeated(args: list[str], times: int, cold: bool = False) -> tuple[float, float, float, int]:
    """``measure`` run ``times`` times: median CPU and wall time, highest peak, first failure."""
    runs = [measure(args, cold) for _ in range(max(1, times))]
    cpu, wall = (float(np.median([r[k] for r in runs])) for k in (0, 1))
    return cpu, wall, max(r[2] for r in runs), next((r[3] for r in runs if r[3]), 0)


def make_recordings(folder: Path, duration_s: int) -> tuple[Path, Path]:
    """The planar and static recordings of one duration (reused if present)."""
    from pendsim_bridge.run.record import RecordSpec, record

    planar, static = folder / f"planar_{duration_s}.mcap", folder / f"static_{duration_s}.mcap"
    start_ns = 1_700_000_000_000_000_000
    for path, spec in (
        (planar, RecordSpec(duration_s=float(duration_s), hold_s=1.0)),
        (static, RecordSpec(duration_s=float(duration_s), model="static")),
    ):
        if not path.exists():
            t0 = time.perf_counter()
            record(spec, path, start_time_ns=start_ns)
            print(f"  wrote {path.name}: {path.stat().st_size / 1e6:.0f} MB in {time.perf_counter() - t0:.0f} s")
    return planar, static


def label(duration_s: int) -> str:
    return f"{duration_s // 3600} h" if duration_s >= 3600 else f"{duration_s} s"


MEASUREMENTS = (
    "anchor: MuJoCo rollout",
    "validate --damping recorded",
    "validate",
    "view --save",
    "anchor: read once + allantools",
    "allan (plots)",
)
"""What the bench measures, by the names ``--skip`` takes, in the order it runs them."""


def durations_s(text: str) -> list[int]:
    """``--durations``: positive whole seconds, comma-separated."""
    try:
        values = [int(float(d)) for d in text.split(",") if d.strip()]
    except ValueError:
        values = []
    if not values or min(values) <= 0:
        raise argparse.ArgumentTypeError(
            f"durations must be positive seconds separated by commas (e.g. 120,3600), got {text!r}"
        )
    return values


def measurement_names(text: str) -> set[str]:
    """``--skip``: names from MEASUREMENTS, comma-separated."""
    names = {s.strip() for s in text.split(",") if s.strip()}
    unknown = sorted(names - set(MEASUREMENTS))
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown measurement {unknown[0]!r}; allowed: {', '.join(MEASUREMENTS)}")
    return names


def main() -> None:
    parser = argparse.ArgumentParser(
        description=" ".join(__doc__.split("\n\n")[0].split()),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--durations", type=durations_s, default="120,3600,21600", help="recording durations, s, comma-separated"
    )
    parser.add_argument("--keep", type=Path, help="folder for the recordings (kept, reused); default a temporary one")
    parser.add_argument(
        "--skip",
        type=measurement_names,
        default="",
        help=f"comma-separated measurements to skip, by name: {', '.join(MEASUREMENTS)}",
    )
    parser.add_argument(
        "--fit-6h", action="store_true", help="also run the default validate (with the damping fit) on 6 h (slow)"
    )
    parser.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="run each measurement this many times: the median CPU and wall time, the highest peak (a 2-core "
        "machine's wall times spread by 20 %% from run to run)",
    )
    parser.add_argument(
        "--cold",
        action="store_true",
        help="first runs: each run with a fresh, empty NUMBA_CACHE_DIR (numba compiles inside it, as after installing)",
    )
    args = parser.parse_args()
    durations, skip = args.durations, args.skip
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        out = Path(tmp) / "out"
        out.mkdir()  # view --save writes a file into it: it must exist whatever is skipped
        rows = []
        for d in durations:
            print(f"{label(d)}: recordings", flush=True)
            planar, static = make_recordings(folder, d)
            runs = {
                "anchor: MuJoCo rollout": [py, "-c", ROLLOUT, str(d)],
                "validate --damping recorded": [py, "-c", CLI, "validate", str(planar), "--damping", "recorded",
                                                "-o", str(out / f"v{d}"), "--force"],
                "validate": [py, "-c", CLI, "validate", str(planar), "-o", str(out / f"vi{d}"), "--force"],
                "view --save": [py, "-c", CLI, "view", str(planar), "--save", str(out / f"{d}.rrd"), "--force"],
                "anchor: read once + allantools": [py, "-c", ALLANTOOLS, str(static)],
                "allan (plots)": [py, "-c", CLI, "allan", str(static), "--plot-dir", str(out / f"a{d}"), "--force"],
            }  # fmt: skip
            assert tuple(runs) == MEASUREMENTS
            anchor_cpu = {}
            for name, cmd in runs.items():
                if name in skip or (name == "validate" and d > 3600 and not args.fit_6h):
                    continue
                load = os.getloadavg()[0]
                cpu, wall, peak, code = repeated(cmd, args.repeat, args.cold)
                if name.startswith("anchor"):
                    anchor_cpu[name] = (cpu, wall)
                rows.append((name, d, cpu, wall, peak, load, code))
                print(f"  {name:32} {cpu:8.1f} s CPU {wall:8.1f} s wall {peak:7.0f} MB  (load {load:.1f})", flush=True)
            rows.append(("-", d, anchor_cpu, 0, 0, 0, 0))
    print_table(rows, args.cold)


def print_table(rows: list, cold: bool = False) -> None:
    """Markdown table: measurement, duration, CPU, wall, peak, target, ratio to its anchor."""
    first = ", first runs (empty numba cache)" if cold else ""
    print(f"\n{datetime.date.today()}, {os.cpu_count()} cores, load average now {os.getloadavg()[0]:.1f}{first}\n")
    print("| measurement | recording | CPU s | wall s | peak MB | x anchor (CPU) | target | met |")
    print("|---|---|---:|---:|---:|---:|---|---|")
    anchors: dict[int, dict] = {r[1]: r[2] for r in rows if r[0] == "-"}
    for name, d, cpu, wall, peak, _load, code in rows:
        if name == "-":
            continue
        anchor = anchors.get(d, {})
        base = anchor.get("anchor: read once + allantools" if name.startswith("allan") else "anchor: MuJoCo rollout")
        ratio = f"{cpu / base[0]:.1f}" if base and not name.startswith("anchor") else ""
        target = (COLD_TARGETS if cold else {}).get((name, d), TARGETS.get((name, d)))
        text, met = "", ""
        if target is not None:
            cpu_t, wall_t, peak_t = target
            parts, ok = [], code == 0 and peak <= peak_t
            if cpu_t is not None:
                parts.append(f"<= {cpu_t:g} s CPU")
                ok = ok and cpu <= cpu_t
            if wall_t is not None:
                parts.append(f"<= {wall_t:g} s wall")
                ok = ok and wall <= wall_t
                if base:
                    parts.append("< anchor wall")
                    ok = ok and wall < base[1]
            parts.append(f"<= {peak_t:g} MB")
            text, met = ", ".join(parts), "yes" if ok else "no"
        fail = " (failed)" if code else ""
        print(f"| {name}{fail} | {label(d)} | {cpu:.1f} | {wall:.1f} | {peak:.0f} | {ratio} | {text} | {met} |")


if __name__ == "__main__":
    main()
