"""Calibration on recordings as the sensor model makes them (issue 22's "done when"): rigs whose
springs, inertias, centres of mass and anchor lengths are drawn within +-5 % of the paper's
(seeded), recorded for 60 s by ``pendsim record`` (MuJoCo, the BNO055 model: heading, a glued-on
mount, packet loss in bursts, clock drift between the nodes, noise), calibrated on the paper's
parameters. Counts how many quantities reported as determined lie within their 95 % intervals
(target 90-99 %), and validates the first recordings with the paper's and the calibrated rig
(target: max |Delta phi1| over the run below 0.02 rad where the paper's give about 0.5 rad).

Run: python bench/bench_calibrate_coverage.py [--rigs 20] [--validate 5]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from pendsim_bridge.cli import main as cli
from pendsim_bridge.run.calibrate import calibrate_recordings
from pendsim_mj.calibration import QUANTITIES
from pendsim_mj.engines import fast_planar
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import RigParams

PAPER = RigParams()
DRAWN = ("c1_n_m", "c2_n_m", "j1_kg_m2", "j2_kg_m2", "oc1_m", "oc2_m", "l01_m", "l04_m", "l05_m", "l08_m",
         "l24_m", "l34_m", "l68_m", "l78_m")  # fmt: skip


def draw(rng: np.random.Generator) -> RigParams:
    while True:  # physical: a draw with J below m OC^2 is drawn again
        try:
            return PAPER.with_mapping({n: PAPER.as_dict()[n] * rng.uniform(0.95, 1.05) for n in DRAWN})
        except ParameterError:
            continue


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", type=int, default=20)
    parser.add_argument("--validate", type=int, default=5, help="validate the first N before and after")
    args = parser.parse_args()
    rng = np.random.default_rng(22)
    hits = total = 0
    worst_before, worst_after = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.rigs):
            rig = draw(rng)
            rig_file = Path(tmp) / f"rig{seed}.json"
            rig_file.write_text(json.dumps({n: rig.as_dict()[n] for n in DRAWN}))
            rec = Path(tmp) / f"rec{seed}.mcap"
            cli(["record", "-o", str(rec), "--params-file", str(rig_file), "--duration-s", "60", "--seed", str(seed),
                 "--phi1-deg", str(rng.uniform(20, 40)), "--phi2-deg", str(rng.uniform(-10, 10)),
                 "--heading-deg", str(rng.uniform(0, 360)), "--mount-misalignment-deg", "5", "--packet-loss", "0.02",
                 "--clock-drift-ppm", "40"])  # fmt: skip
            report = calibrate_recordings([rec], PAPER, checks=seed < args.validate)
            cal = report.calibration
            coef = fast_planar.coefficients([rig])[:, 0]
            truth = {q.name: q.of(coef) for q in QUANTITIES} | rig.as_dict()
            inside = [abs(q.value - truth[q.name]) <= q.half_width95 for q in cal.quantities if q.determined]
            hits += sum(inside)
            total += len(inside)
            line = f"rig {seed:2d}: residual {cal.residual_rms_sigma:.2f} sigma, "
            line += f"{sum(inside)}/{len(inside)} determined inside"
            if report.before:
                before, after = report.before[0].max_abs_phi1_rad, report.after[0].max_abs_phi1_rad
                worst_before.append(before)
                worst_after.append(after)
                line += f"; max |dphi1| paper {before:.3f} rad, calibrated {after:.4f} rad"
            print(line, flush=True)
    print(f"coverage: {hits}/{total} = {100 * hits / total:.1f} % of determined quantities within their 95 % intervals")
    if worst_after:
        print(f"validation: paper's rig up to {max(worst_before):.3f} rad, calibrated up to {max(worst_after):.4f} rad")


if __name__ == "__main__":
    main()
