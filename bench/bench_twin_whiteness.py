"""The live twin's innovations on healthy emulated runs: are they white? ``pendsim nodes``'s plan
(the simulated rig through the BNO055 model) fed in time order into ``TwinSession``, as
``bench_twin_faults`` feeds it, one 60 s free decay per seed. Measured per node and channel (the
swing angle, the hinge rate): the Ljung-Box p-value of the normalised innovations over 20 lags (the
session's own ``whiteness_p``, 4400-4800 values each: lag correlations beyond about 0.03 fail),
the largest autocorrelation over lags 1-10, and the mean NIS; the same for the accelerometer's
tangential and normal readings (``RigEstimator.update_accel``).

Sets of imperfections (each on top of noise and quantisation):
- ``all``: ``bench_twin_faults.imperfect`` (random release 10-45 deg, random heading, nodes glued
  2 deg askew, fusion error 0.2 deg, hold wobble, 2 % packet loss);
- ``no-fusion-error``: the same without the fused orientation's slowly varying error;
- ``drift``: ``all`` with M2's clock 30 ppm fast.

Run: python bench/bench_twin_whiteness.py [--seeds 8] [--run-s 62] [--sets all,no-fusion-error,drift]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_twin_faults import imperfect, run


def without(args: list[str], option: str) -> list[str]:
    i = args.index(option)
    return args[:i] + args[i + 2 :]


SETS = {
    "all": lambda seed: imperfect(seed),
    "no-fusion-error": lambda seed: without(imperfect(seed), "--fusion-error-deg"),
    "drift": lambda seed: [*imperfect(seed), "--clock-drift-ppm", "m2=30"],
}
CHANNELS = ("M1 angle", "M1 rate", "M2 angle", "M2 rate", "M1 acc t", "M1 acc n", "M2 acc t", "M2 acc n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--run-s", type=float, default=62.0)
    ap.add_argument("--sets", default=",".join(SETS))
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}; {args.seeds} seeds of {args.run_s:g} s each")
    for name in args.sets.split(","):
        p, rho, nis = [], [], []
        for seed in range(args.seeds):
            session, _ = run(args.run_s, SETS[name](seed))
            summary = session.summary()
            p.append([v for node in (*summary.whiteness_p, *summary.accel_whiteness_p) for v in node])
            series = [w for node in (*session._whiteness, *session._accel_whiteness) for w in node]
            rho.append([float(np.max(np.abs(w.autocorrelation()[:10]))) for w in series])
            nis.append((*summary.nis_mean, *summary.accel_nis_mean))
        p_, rho_, nis_ = np.array(p), np.array(rho), np.array(nis)
        print(f"\n{name}: mean NIS M1 {nis_[:, 0].mean():.2f} (max {nis_[:, 0].max():.2f}), "
              f"M2 {nis_[:, 1].mean():.2f} (max {nis_[:, 1].max():.2f}); accelerometer M1 {nis_[:, 2].mean():.2f} "
              f"(max {nis_[:, 2].max():.2f}), M2 {nis_[:, 3].mean():.2f} (max {nis_[:, 3].max():.2f})")  # fmt: skip
        print(f"  {'channel':<9} {'white (p > 0.01)':>17} {'median p':>9} {'max |rho| 1-10, median':>23}")
        for j, channel in enumerate(CHANNELS):
            white = int(np.sum(p_[:, j] > 0.01))
            median_p, median_rho = np.median(p_[:, j]), np.median(rho_[:, j])
            print(f"  {channel:<9} {white:>11} of {args.seeds:<3} {median_p:>9.3f} {median_rho:>23.3f}")


if __name__ == "__main__":
    main()
