"""Coverage of the spatial tilt fit's 95 % intervals (``spatial_identification.fit_tilt``, start
state fitted): seeded synthetic records from the spatial MuJoCo model through the BNO055 model,
aligned as ``identify --model spatial`` aligns a recording, at the default tilt values and away
from them; prints per setting how often the intervals cover the true tilt stiffness, tilt
damping, b1, b2, the median |error| / half-width and the fits' time.

Run: python bench/bench_spatial_coverage.py [--records 40] [--duration-s 12] [--tilt-start zero]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from pendsim_bridge.run.spatial_validate import gyro_in_swing_frames
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.alignment import MeasuredRun, NodeSamples, align
from pendsim_mj.estimation.spatial_identification import NAMES, TiltFit, fit_tilt, static_tilt_rad
from pendsim_mj.rig.model import SPATIAL
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import Bno055, sample_imu

SETTINGS = {  # tilt stiffness N m/rad, tilt damping N m s/rad
    "defaults": (2.0, 0.0007),
    "stiff 3, damping 0.0015": (3.0, 0.0015),
    "stiff 5, damping 0.0015": (5.0, 0.0015),
}


def spatial_run(
    truth: RigParams,
    seed: int,
    phi0_rad: tuple[float, float],
    *,
    duration_s: float = 12.0,
    hold_s: float = 1.0,
    tilt_start: str = "zero",
) -> MeasuredRun:
    """One synthetic spatial record (held ``hold_s``, released from ``phi0_rad``), aligned."""
    tilt0 = static_tilt_rad(truth, phi0_rad) if tilt_start == "static" else (0.0, 0.0)
    traj = simulate(truth, phi0_rad, (0.0, 0.0), duration_s, 0.01, variant=SPATIAL, tilt0_rad=tilt0)
    config = Bno055(seed=seed)
    imu = sample_imu(traj, config, hold_s=hold_s)
    nodes = []
    for k in range(2):
        stamp, log, received = imu.node_times(k)
        values = (imu.quat_wxyz[received, k], imu.gyro_rad_s[received, k], imu.accel_m_s2[received, k])
        nodes.append(NodeSamples(log[received], *values, stamp_s=stamp[received]))
    return align(nodes, truth, fusion_rate_hz=config.fusion_rate_hz)


def fit_run(truth: RigParams, run: MeasuredRun, tilt_start: str = "zero") -> TiltFit:
    """The tilt fit of an aligned run, started from the assumed defaults."""
    base = truth.with_mapping({n: getattr(DEFAULT_PARAMS, n) for n in NAMES})
    t, gyro, sigma = gyro_in_swing_frames(run, [None, None])
    return fit_tilt(
        base, run.start.phi_rad, t, gyro, sigma, omega0_rad_s=run.start.omega_rad_s, tilt_start=tilt_start,
        timing_range_s=run.relative_timing_range_s,
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--records", type=int, default=40)
    parser.add_argument("--duration-s", type=float, default=12.0)
    parser.add_argument("--tilt-start", default="zero", choices=("zero", "static"))
    args = parser.parse_args()
    for label, (stiffness, damping) in SETTINGS.items():
        rng = np.random.default_rng(7)
        covered = np.zeros(len(NAMES))
        ratio = []
        seconds = 0.0
        rms = []
        for i in range(args.records):
            truth = DEFAULT_PARAMS.with_overrides(
                plane_offset_m=0.05,
                tilt_stiffness_n_m_rad=stiffness,
                tilt_damping_n_m_s_rad=damping,
                b1_n_m_s=float(rng.uniform(4e-4, 1.2e-3)),
                b2_n_m_s=float(rng.uniform(2e-4, 1e-3)),
            )
            phi0 = (math.radians(float(rng.uniform(20, 40))), 0.0)
            run = spatial_run(truth, 1000 + i, phi0, duration_s=args.duration_s, tilt_start=args.tilt_start)
            start = time.perf_counter()
            fit = fit_run(truth, run, args.tilt_start)
            seconds += time.perf_counter() - start
            true = np.array([getattr(truth, n) for n in NAMES])
            got = np.array([fit.value(n) for n in NAMES])
            half = np.array([fit.half_width(n) for n in NAMES])
            covered += np.abs(got - true) <= half
            ratio.append(np.abs(got - true) / half)
            rms.append(fit.residual_rms_sigma)
        cover = ", ".join(f"{n} {c / args.records:.0%}" for n, c in zip(NAMES, covered, strict=True))
        med = ", ".join(f"{v:.2f}" for v in np.median(ratio, axis=0))
        print(
            f"{label}: {args.records} records of {args.duration_s:g} s, tilt start {args.tilt_start}: covered {cover}; "
            f"median |error|/half-width {med}; residual {np.median(rms):.3f} sigma rms (median); "
            f"{seconds / args.records:.2f} s per fit",
            flush=True,
        )


if __name__ == "__main__":
    main()
