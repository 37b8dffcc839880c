"""End-to-end Allan analysis of a 6 h, 80 Hz, two-node static recording (12 axes).

Run: python bench/bench_allan.py [--hours 6]

Writes the recording first (not timed), then times reading the IMU topics, the deviations with
confidence intervals and noise terms (the numba kernel on each node's phase, as ``pendsim allan``
computes them), and the plots; and, for comparison in the same run, allantools.oadev on one axis
with the same tau grid (the baseline the issue names). The first run includes numba's compile of
the kernel where its cache is cold. Targets (issue 5): read + deviations + plots under 10 s on the
2-core machine; end to end, with the process's imports and peak memory, see bench_long.py
(issue 16: 5 s wall, 600 MB).
"""

from __future__ import annotations

import argparse
import gc
import tempfile
import time
from pathlib import Path

import allantools
import numpy as np

from pendsim_bridge.io.recording import RunInfo, imu_topic, read_recording, write_recording
from pendsim_bridge.report import allan_report
from pendsim_mj.allan.deviation import curves_of_phase, noise_terms, phase, tau_grid
from pendsim_mj.rig.model import exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, ImuNoise, static_imu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=6.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    duration = args.hours * 3600
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "static.mcap"
        noise = ImuNoise(gyro_bias_instability_rad_s=(2e-4,) * 3, accel_bias_walk_m_s2_per_sqrt_s=(1e-4,) * 3)
        start = time.perf_counter()
        imu = static_imu(DEFAULT_PARAMS, duration, Bno055(noise_model=noise))
        run = RunInfo("static", (0.0, 0.0), (0.0, 0.0), duration, 0.0125, model="static")
        write_recording(path, imu, run, exact_mjcf(DEFAULT_PARAMS), DEFAULT_PARAMS)
        print(
            f"{args.hours:g} h static recording: {len(imu.t_s):,} samples per node, "
            f"{path.stat().st_size / 1e6:.0f} MB, written in {time.perf_counter() - start:.1f} s (not timed below)"
        )

        del imu
        gc.collect()
        phases = {"read": [], "compute": [], "plots": []}
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            rec = read_recording(path, topics=[imu_topic("m1"), imu_topic("m2")])
            t1 = time.perf_counter()
            curves = []
            for n in ("m1", "m2"):  # per node, from the recording's own arrays (no joined copy)
                curves += curves_of_phase(phase(rec.imu[n].accel_m_s2, rec.imu[n].gyro_rad_s), 80.0)
            [noise_terms(c) for c in curves]
            t2 = time.perf_counter()
            report = allan_report.analyse(path)  # the command's own path, for the plots
            t3 = time.perf_counter()
            allan_report.plots(report, Path(tmp) / "plots")
            t4 = time.perf_counter()
            phases["read"].append(t1 - t0)
            phases["compute"].append(t2 - t1)
            phases["plots"].append(t4 - t3)
            del rec, report
            gc.collect()
        best = {k: min(v) for k, v in phases.items()}
        for name, label in (
            ("read", "read IMU topics"),
            ("compute", "deviations + CI + terms"),
            ("plots", "plots (4 PNG)"),
        ):
            spread = ", ".join(f"{v:.2f}" for v in phases[name])
            print(f"{label:24} {best[name]:6.2f} s   (runs: {spread})")
        taus = len(curves[0].tau_s)
        print(f"{'total (best phases)':24} {sum(best.values()):6.2f} s   (target < 10 s; {taus} taus per axis)")
        worst = max(sum(p[i] for p in phases.values()) for i in range(args.repeat))
        print(f"{'total (slowest run)':24} {worst:6.2f} s")

        rec = read_recording(path, topics=[imu_topic("m1")])
        gyro_x = np.ascontiguousarray(rec.imu["m1"].gyro_rad_s[:, 0])
        m = tau_grid(len(gyro_x))
        start = time.perf_counter()
        allantools.oadev(gyro_x, rate=80.0, data_type="freq", taus=m / 80.0)
        one = time.perf_counter() - start
        print(
            f"baseline allantools.oadev, one axis, same grid: {one:.2f} s -> x12 = {12 * one:.1f} s; "
            f"ours for 12 axes with CIs: {t2 - t1:.2f} s ({12 * one / (t2 - t1):.1f}x faster)"
        )


if __name__ == "__main__":
    main()
