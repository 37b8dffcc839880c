"""The live twin's estimator and health monitor on emulated data (the BNO055 sensor model on
MuJoCo runs, a motor on M1 driving near mode 1 so that the rig keeps swinging): the false alarms
over healthy hours, each scripted fault's detection time and attribution, and the cost of one
update against one bare RK4 step of the same batch (measured in the same run).

Run: python bench/bench_twin.py [--hours 1] [--faults-seeds 3]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from pendsim_mj.control.plant import FastPlant
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.swing_frame import twist_angle
from pendsim_mj.rig.drives import Drive, Sine
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu, static_imu
from pendsim_mj.twin.estimator import RigEstimator
from pendsim_mj.twin.health import HealthMonitor

TRACKED = (
    "b1_n_m_s",
    "b2_n_m_s",
    "friction1_n_m",
    "friction2_n_m",
    "coupling_sin_n_m",
    "offset_m1_rad",
    "offset_m2_rad",
)
DRIVE_N_M, DRIVE_HZ, STEP_S, PIECE_S = 0.01, 0.877, 0.0125, 300.0
REST = static_imu(DEFAULT_PARAMS, 1.0, Bno055(noise=False)).quat_wxyz[0]
FAULTS = {
    "mount slip M1 3 deg": ({}, math.radians(3.0), "offset_m1_rad"),
    "coupling springs -5 %": ({"c1_n_m": 0.95 * DEFAULT_PARAMS.c1_n_m}, 0.0, "coupling_sin_n_m"),
    "damping M1 doubled": ({"b1_n_m_s": 2 * DEFAULT_PARAMS.b1_n_m_s}, 0.0, "b1_n_m_s"),
    "dry friction M1 2e-4 N m": ({"friction1_n_m": 2e-4}, 0.0, "friction1_n_m"),
}


class Stream:
    """Piece after piece of measured samples of a rig that may change between pieces."""

    def __init__(self, seed: int) -> None:
        self.phi0, self.omega0, self.start, self.seed = (math.radians(30), 0.0), (0.0, 0.0), 0.0, seed

    def piece(self, duration_s: float, rig: dict[str, float], slip_rad: float):
        phase = (2 * math.pi * DRIVE_HZ * self.start) % (2 * math.pi)
        drive = Drive(torque_m1=Sine(DRIVE_N_M, DRIVE_HZ, phase_rad=phase))
        run = simulate(DEFAULT_PARAMS.with_overrides(**rig), self.phi0, self.omega0, duration_s, STEP_S, drive=drive)
        imu = sample_imu(run, Bno055(fusion_timing=False, seed=self.seed))
        self.seed += 1
        hinge = np.array([0.0, 0.0, 1.0])
        phi = np.stack([twist_angle(imu.quat_wxyz[:, n], REST[n], hinge) for n in range(2)], axis=1)
        phi[:, 0] += slip_rad
        t = imu.t_s[1:] + self.start
        out = t, phi[1:], imu.gyro_rad_s[1:, :, 2]
        self.phi0, self.omega0 = tuple(run.phi_rad[-1]), tuple(run.omega_rad_s[-1])
        self.start += duration_s
        return out


def feed(estimator: RigEstimator, monitor: HealthMonitor, t, phi, omega) -> list:
    alarms = []
    for k in range(len(t)):
        torque = (DRIVE_N_M * math.sin(2 * math.pi * DRIVE_HZ * (t[k] - 0.5 * STEP_S)), 0.0)
        for node in range(2):
            estimator.update(t[k], node, phi[k, node], omega[k, node], torques_n_m=torque)
        alarms += monitor.check()
    return alarms


def new_twin(phi, omega) -> tuple[RigEstimator, HealthMonitor]:
    estimator = RigEstimator(DEFAULT_PARAMS, nodes=Bno055(fusion_timing=False), track=TRACKED)
    estimator.start(0.0, [phi[0, 0], phi[0, 1], omega[0, 0], omega[0, 1]])
    return estimator, HealthMonitor(estimator)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--faults-seeds", type=int, default=3)
    args = parser.parse_args()

    # cost of one update against one bare RK4 step of the same batch of sigma points
    stream = Stream(1)
    t, phi, omega = stream.piece(60.0, {}, 0.0)
    estimator, monitor = new_twin(phi, omega)
    start = time.process_time()
    feed(estimator, monitor, t, phi, omega)
    per_update = (time.process_time() - start) / (2 * len(t))
    plant = FastPlant(DEFAULT_PARAMS, nenv=2 * estimator.n + 1)
    u = np.zeros((4, plant.nenv))
    start = time.process_time()
    for _ in range(2000):
        plant.advance(u)
    per_step = (time.process_time() - start) / 2000
    print(f"one update: {per_update * 1e6:.0f} us CPU ({estimator.n} states, {plant.nenv} sigma points); "
          f"a bare RK4 step of that batch: {per_step * 1e6:.0f} us; two nodes at 80 Hz: "
          f"{100 * per_update * 160:.1f} % of a core")  # fmt: skip

    # false alarms over healthy hours (one long run, piece by piece)
    stream = Stream(100)
    t, phi, omega = stream.piece(PIECE_S, {}, 0.0)
    estimator, monitor = new_twin(phi, omega)
    alarms = feed(estimator, monitor, t, phi, omega)
    while stream.start < args.hours * 3600 - 1e-9:
        alarms += feed(estimator, monitor, *stream.piece(PIECE_S, {}, 0.0))
    largest = max(monitor.largest_z().values())
    print(f"healthy {args.hours:g} h: {len(alarms)} false alarms; largest |z| {largest:.2f} (threshold "
          f"{monitor.threshold:g})")  # fmt: skip
    for alarm in alarms:
        print("  ", alarm.describe())

    # each fault at 60 s, watched for 60 s after it
    print(f"\n{'fault':<28}{'seed':>5}{'alarmed after':>15}  first alarm")
    for name, (rig, slip, parameter) in FAULTS.items():
        for seed in range(args.faults_seeds):
            stream = Stream(1000 + 10 * seed)
            t, phi, omega = stream.piece(60.0, {}, 0.0)
            estimator, monitor = new_twin(phi, omega)
            feed(estimator, monitor, t, phi, omega)
            alarms = feed(estimator, monitor, *stream.piece(60.0, rig, slip))
            first = alarms[0] if alarms else None
            after = f"{first.t_s - 60.0:.1f} s" if first else "none"
            right = "" if first is None else ("right" if first.parameter == parameter else "WRONG")
            print(f"{name:<28}{seed:>5}{after:>15}  {right} {first.describe() if first else ''}")


if __name__ == "__main__":
    main()
