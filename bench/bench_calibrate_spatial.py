"""calibrate --model spatial on seeded synthetic rigs: coverage of the determined quantities'
95 % intervals, validation before and after, and CPU time against the planar calibration of the
same recordings (measured in the same run).

Each rig: the paper's with c1, c2, J1, J2, OC1, OC2 drawn within +-5 %, the tilt stiffness and
damping within +-30 % of the assumed 2.0 N m/rad and 0.0007 N m s/rad, planes 50 mm apart,
recorded with ``pendsim record --model spatial`` (BNO055 noise, fusion timing, seed per rig),
released from 25-35 deg. Truth of each reported quantity: its value at the drawn rig
(``ParameterSpace.quantity_value``, the quantity's definition). Validation: ``pendsim validate
--model spatial`` with the stated and with the calibrated rig (max |Delta phi1| over the run).

Run: python bench/bench_calibrate_spatial.py [--rigs 10] [--duration-s 40]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from pendsim_bridge.cli import main as cli
from pendsim_bridge.run.calibrate import calibrate_recordings
from pendsim_bridge.run.validate import validate
from pendsim_mj.calibration.fit import LOSSES
from pendsim_mj.calibration.parameters import QUANTITIES, SPATIAL_QUANTITIES, ParameterSpace, parameter_quantity
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import RigParams

DRAWN = ("c1_n_m", "c2_n_m", "j1_kg_m2", "j2_kg_m2", "oc1_m", "oc2_m")


def drawn_rig(seed: int) -> dict[str, float]:
    """A rig drawn within the ranges above (drawn again where it is no rig: J below m OC^2)."""
    rng = np.random.default_rng(seed)
    paper = RigParams().as_dict()
    while True:
        rig = {n: paper[n] * (1 + rng.uniform(-0.05, 0.05)) for n in DRAWN}
        rig["tilt_stiffness_n_m_rad"] = 2.0 * (1 + rng.uniform(-0.3, 0.3))
        rig["tilt_damping_n_m_s_rad"] = 0.0007 * (1 + rng.uniform(-0.3, 0.3))
        try:
            RigParams().with_mapping(rig)
        except ParameterError:
            continue
        return rig | {"phi1_deg": float(rng.uniform(25, 35))}


def max_dphi1(path: Path, params: RigParams) -> float:
    report = validate(path, params=params, damping="recorded", model="spatial")
    return float(report.case("mujoco-spatial", "estimated", "whole").comparisons["phi1"].max_abs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rigs", type=int, default=10)
    parser.add_argument("--duration-s", type=float, default=40.0)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args()
    inside = total = 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.rigs):
            rig = drawn_rig(seed)
            phi1 = rig.pop("phi1_deg")
            rig_file = Path(tmp) / f"rig{seed}.json"
            rig_file.write_text(json.dumps(rig))
            rec = Path(tmp) / f"rec{seed}.mcap"
            cli(["record", "-o", str(rec), "--model", "spatial", "--offset-m", "0.05", "--params-file",
                 str(rig_file), "--duration-s", str(args.duration_s), "--phi1-deg", f"{phi1:.3f}",
                 "--seed", str(100 + seed)])  # fmt: skip
            start = time.process_time()
            planar = calibrate_recordings([rec], RigParams(), checks=False)
            planar_cpu = time.process_time() - start
            start = time.process_time()
            report = calibrate_recordings([rec], RigParams(), checks=False, model="spatial")
            spatial_cpu = time.process_time() - start
            cal = report.calibration
            truth = RigParams(plane_offset_m=0.05).with_mapping(rig)
            space = ParameterSpace(truth, cal.free)
            candidates = {q.name: q for q in (*QUANTITIES, *SPATIAL_QUANTITIES)}
            misses = []
            for q in cal.quantities:
                if not q.determined:
                    continue
                quantity = candidates.get(q.name) or parameter_quantity(q.name, q.unit)
                true = space.quantity_value(quantity, np.zeros(len(cal.free)))
                total += 1
                if abs(q.value - true) <= q.half_width95:
                    inside += 1
                else:
                    misses.append(f"{q.name} {(q.value - true) / q.half_width95:+.2f} hw")
            losses = {n: v for n, v in cal.overrides().items() if n in LOSSES}
            before = max_dphi1(rec, cal.stated.with_mapping(losses))
            after = max_dphi1(rec, cal.params)
            row = {
                "seed": seed, "residual_sigma": round(cal.residual_rms_sigma, 3),
                "planar_residual_sigma": round(planar.calibration.residual_rms_sigma, 3),
                "determined": sum(q.determined for q in cal.quantities),
                "misses": misses, "dphi1_before_rad": round(before, 4), "dphi1_after_rad": round(after, 4),
                "cpu_spatial_s": round(spatial_cpu, 1), "cpu_planar_s": round(planar_cpu, 1),
            }  # fmt: skip
            rows.append(row)
            print("\n" + json.dumps(row), flush=True)
    cpu = [r["cpu_spatial_s"] / r["cpu_planar_s"] for r in rows]
    print(
        f"coverage: {inside} of {total} determined quantities within their 95 % intervals "
        f"({100 * inside / max(total, 1):.1f} %); spatial / planar CPU: {np.median(cpu):.1f}x (median)"
    )


if __name__ == "__main__":
    main()
