"""Sweeps at the engine's speed (issue 24), end to end, in one run: whole ``pendsim sweep``
processes (imports, kernels, features, Parquet) against an independent plain numba RK4 that
integrates the same cases to their end states only, on the same cores.

Run: python bench/bench_sweep_scale.py [--cases 20000] [--repeat 3] [--mujoco-cases 4000]
     [--million]   (about 4 minutes; --million adds the 1e6-case sweep, about 4 more)

Targets (issue 24; a quiet machine, load printed):
- a 20 000-case sweep (30 s each at 10 ms; frequency, amplitude and energy; Parquet; no plots)
  takes at most 3x the plain numba RK4 of the same cases;
- ``--workers 2`` on that sweep is not slower than serial (the fast engine runs on the kernel's
  threads in this process); a MuJoCo-engine sweep runs at least 1.7x faster on the machine's
  cores than on one. The issue asked it of ``--workers 2`` against serial, written when a serial
  MuJoCo sweep ran on one core; it now runs one MuJoCo thread per core in this process, so the
  bench pins the same serial sweep to one core for the cores' gain, and reports ``--workers 2``
  against serial (nothing left for workers to add on one machine: about 1.0x). 4000 cases by
  default: at 1000 the sweep's start-up on one core (imports, model, Parquet: about 1.5 s) bounds
  the gain at 1.6-1.7x;
- a 1e6-case sweep completes in under 5 minutes with flat memory (its peak RSS about that of a
  1e5-case sweep).

Every sweep is a fresh process (``python -m pendsim_bridge.cli sweep``) timed with /usr/bin/time
(wall s, CPU s, peak RSS); the baseline is timed in this process after its compile (steady state,
best of --repeat). Both use every core.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from pendsim_mj.engines import fast_planar
from pendsim_mj.sweep.plan import SweepPlan

DURATION_S = 30.0
DT_S = 0.01
VARY = ["--vary=phi1_deg=-120:120", "--vary=phi2_deg=-120:120", "--vary=c1_n_m=4:8"]
FEATURES = "frequency,amplitude,energy"


@numba.njit(inline="always", cache=True)
def _rates(q1: float, q2: float, v1: float, v2: float, k: tuple) -> tuple[float, float]:  # type: ignore[type-arg]
    j1, j2, b1, b2, g1, g2, ks, kc, fs, fc = k
    d = q2 - q1
    m1 = ks * math.sin(d) - kc * math.cos(d)
    m2 = -m1 - fs * math.sin(q2) + fc * math.cos(q2)
    return (-g1 * math.sin(q1) + m1 - b1 * v1) / j1, (-g2 * math.sin(q2) + m2 - b2 * v2) / j2


@numba.njit(parallel=True, cache=True)
def plain_rk4(k: np.ndarray, y: np.ndarray, nstep: int, h: float) -> np.ndarray:
    """The baseline: classical RK4 of the planar equations, one case per iteration of a parallel
    loop, library sin/cos, end states only (written here from the equations of RIG.md, not from
    the engine's kernel). k: (NCOEF, n) force-law constants (``fast_planar.COEFFICIENTS``)."""
    n = y.shape[1]
    out = np.empty((4, n))
    for i in numba.prange(n):
        c = (k[0, i], k[1, i], k[2, i], k[3, i], k[4, i], k[5, i], k[6, i], k[7, i], k[8, i], k[9, i])
        p1, p2, w1, w2 = y[0, i], y[1, i], y[2, i], y[3, i]
        hh = 0.5 * h
        for _ in range(nstep):
            a1, a2 = _rates(p1, p2, w1, w2, c)
            b1, b2 = _rates(p1 + hh * w1, p2 + hh * w2, w1 + hh * a1, w2 + hh * a2, c)
            v1, v2 = w1 + hh * a1, w2 + hh * a2
            c1, c2 = _rates(p1 + hh * v1, p2 + hh * v2, w1 + hh * b1, w2 + hh * b2, c)
            x1, x2 = w1 + hh * b1, w2 + hh * b2
            d1, d2 = _rates(p1 + h * x1, p2 + h * x2, w1 + h * c1, w2 + h * c2, c)
            y1, y2 = w1 + h * c1, w2 + h * c2
            p1 += h / 6 * (w1 + 2 * v1 + 2 * x1 + y1)
            p2 += h / 6 * (w2 + 2 * v2 + 2 * x2 + y2)
            w1 += h / 6 * (a1 + 2 * b1 + 2 * c1 + d1)
            w2 += h / 6 * (a2 + 2 * b2 + 2 * c2 + d2)
        out[0, i], out[1, i], out[2, i], out[3, i] = p1, p2, w1, w2
    return out


def baseline_s(ncases: int, repeat: int) -> tuple[float, float]:
    """Best wall time of the plain RK4 over the sweep's own cases (steady state), and its
    agreement with the engine's end states (max |delta phi|, rad: a check that it does the same work)."""
    plan = SweepPlan.from_mapping({
        "method": "random", "samples": ncases, "seed": 1, "duration_s": DURATION_S,
        "vary": {"phi1_deg": {"from": -120, "to": 120}, "phi2_deg": {"from": -120, "to": 120},
                 "c1_n_m": {"from": 4, "to": 8}},
    })  # fmt: skip
    table = plan.cases()
    params, phi0, omega0 = plan.case_inputs(table, np.arange(ncases))
    coef = fast_planar.coefficients(params)
    y0 = np.concatenate([phi0.T, omega0.T])
    nstep = round(DURATION_S / DT_S)
    plain_rk4(coef[:, :8], y0[:, :8], 10, DT_S)  # compile
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        end = plain_rk4(coef, y0, nstep, DT_S)
        best = min(best, time.perf_counter() - start)
    check = fast_planar.integrate(coef[:, :200], phi0[:200], omega0[:200], nstep, DT_S, save_every=nstep)[-1]
    with np.errstate(invalid="ignore"):
        gap = float(np.nanmax(np.abs(check[:2] - end[:2, :200])))
    return best, gap


def timed(args: list[str], out: Path, cpus: set[int] | None = None) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS MB) of one ``pendsim sweep`` process into a fresh folder (on the
    CPUs ``cpus`` only, when given: the process and its threads pinned there)."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = ["/usr/bin/time", "-f", "%e %U %S %M", sys.executable, "-m", "pendsim_bridge.cli", "sweep", *args,
           "-o", str(out)]  # fmt: skip
    pin = None if cpus is None else (lambda: os.sched_setaffinity(0, cpus))
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, preexec_fn=pin)
    if proc.returncode != 0:
        raise SystemExit(f"sweep failed ({proc.returncode}): {proc.stderr[-2000:]}")
    wall, user, system, rss_kb = proc.stderr.strip().splitlines()[-1].split()
    shutil.rmtree(out, ignore_errors=True)
    return float(wall), float(user) + float(system), float(rss_kb) / 1024


def best(args: list[str], out: Path, repeat: int, cpus: set[int] | None = None) -> tuple[float, float, float]:
    runs = [timed(args, out, cpus) for _ in range(repeat)]
    return min(runs, key=lambda r: r[0])


def verdict(met: bool) -> str:
    return "met" if met else "NOT met"


def fast_args(ncases: int, *more: str) -> list[str]:
    return ["--random", str(ncases), "--seed", "1", *VARY, "--duration-s", str(DURATION_S), "--features", FEATURES,
            "--no-plots", *more]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--mujoco-cases", type=int, default=4000)
    ap.add_argument("--million", action="store_true", help="also the 1e6-case sweep and a 1e5-case one (memory)")
    a = ap.parse_args()
    print(f"cores: {os.cpu_count()}, numba threads: {numba.config.NUMBA_NUM_THREADS}, load: {os.getloadavg()}")
    tmp = Path(tempfile.mkdtemp(prefix="bench-sweep-"))
    try:
        timed(fast_args(100), tmp / "warm")  # kernels loaded into the cache before anything is timed
        base, gap = baseline_s(a.cases, a.repeat)
        print(f"plain numba RK4, {a.cases} cases x {DURATION_S:g} s, end states: {base:.2f} s "
              f"(agrees with the engine to {gap:.1e} rad)")  # fmt: skip
        serial = best(fast_args(a.cases), tmp / "s", a.repeat)
        ratio = serial[0] / base
        print(f"pendsim sweep, {a.cases} cases serial: {serial[0]:.2f} s wall, {serial[1]:.1f} s CPU, "
              f"{serial[2]:.0f} MB -> {ratio:.2f}x the plain RK4 (target <= 3x: {verdict(ratio <= 3)})")  # fmt: skip
        workers = best(fast_args(a.cases, "--workers", "2"), tmp / "w", a.repeat)
        print(f"  --workers 2: {workers[0]:.2f} s wall ({workers[0] / serial[0]:.2f}x serial; target <= 1: "
              f"{'met' if workers[0] <= serial[0] * 1.05 else 'NOT met'}, 5 % timing noise allowed)")  # fmt: skip
        mj = ["--engine", "mujoco", "--random", str(a.mujoco_cases), "--seed", "1", *VARY, "--duration-s", "10",
              "--features", FEATURES, "--no-plots"]  # fmt: skip
        mj_serial = best(mj, tmp / "ms", max(1, a.repeat - 1))
        mj_workers = best([*mj, "--workers", "2"], tmp / "mw", max(1, a.repeat - 1))
        speedup = mj_serial[0] / mj_workers[0]
        print(f"MuJoCo engine, {a.mujoco_cases} cases x 10 s: serial {mj_serial[0]:.2f} s ({mj_serial[1]:.1f} s CPU), "
              f"--workers 2 {mj_workers[0]:.2f} s -> {speedup:.2f}x serial (not slower: "
              f"{'met' if mj_workers[0] <= mj_serial[0] * 1.05 else 'NOT met'}, 5 % timing noise allowed)")  # fmt: skip
        used = mj_serial[1] / mj_serial[0]  # cores the serial run already keeps busy (MuJoCo's rollout threads)
        cores = os.cpu_count() or 1
        print(f"  the serial MuJoCo sweep already keeps {used:.2f} of {cores} cores busy: no split of it over "
              f"{cores} cores can run more than {cores / used:.2f}x faster")  # fmt: skip
        one_core = best(mj, tmp / "m1", max(1, a.repeat - 1), cpus={min(os.sched_getaffinity(0))})
        gain = one_core[0] / mj_serial[0]
        print(
            f"  the same serial sweep pinned to one core: {one_core[0]:.2f} s -> the {cores} cores make it "
            f"{gain:.2f}x faster (serial; target >= 1.7x: {verdict(gain >= 1.7)}), "
            f"{one_core[0] / mj_workers[0]:.2f}x (--workers 2)"
        )
        if a.million:
            small = timed(fast_args(100_000), tmp / "m5")
            large = timed(fast_args(1_000_000), tmp / "m6")
            print(f"1e5 cases: {small[0]:.1f} s wall, {small[2]:.0f} MB; 1e6 cases: {large[0]:.1f} s wall "
                  f"({large[1]:.0f} s CPU), {large[2]:.0f} MB (target < 300 s: {verdict(large[0] < 300)};"
                  f" memory 1e6 / 1e5: {large[2] / small[2]:.2f})")  # fmt: skip
        print(f"load after: {os.getloadavg()}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
