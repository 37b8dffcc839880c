"""Health monitoring on what the BNO055 sensor model measures of a rig whose parameters change
mid-run (the rig simulated piece by piece on MuJoCo, driven by a known torque so that it keeps
swinging): each change is alarmed within 60 s, attributed to its own parameter with since when and
by how much; a healthy run raises none."""

from __future__ import annotations

import math

import numpy as np

from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.swing_frame import twist_angle
from pendsim_mj.rig.drives import Drive, Sine
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu, static_imu
from pendsim_mj.twin.estimator import RigEstimator
from pendsim_mj.twin.health import HealthMonitor

TRACKED = ("b1_n_m_s", "b2_n_m_s", "coupling_sin_n_m", "offset_m1_rad", "offset_m2_rad")
DRIVE_N_M, DRIVE_HZ = 0.01, 0.877  # a motor on M1 near mode 1 keeps the rig swinging
STEP_S = 0.0125  # one simulation step per node sample (80 Hz)


def _torque(t_s: float) -> float:
    return DRIVE_N_M * math.sin(2 * math.pi * DRIVE_HZ * t_s)


def _measured(pieces: list[tuple[float, dict[str, float], float]], seed: int):
    """Each node's (t_s, swing angle, hinge rate) over consecutive pieces (until_s, rig overrides,
    M1's mount slip in rad), the rig continuing from where the last piece left it."""
    rest = static_imu(DEFAULT_PARAMS, 1.0, Bno055(noise=False)).quat_wxyz[0]
    hinge = np.array([0.0, 0.0, 1.0])
    phi0, omega0, start = (math.radians(30), 0.0), (0.0, 0.0), 0.0
    t_all, phi_all, omega_all = [], [], []
    for k, (until_s, rig, slip) in enumerate(pieces):
        phase = 2 * math.pi * DRIVE_HZ * start
        drive = Drive(torque_m1=Sine(DRIVE_N_M, DRIVE_HZ, phase_rad=phase % (2 * math.pi)))
        run = simulate(DEFAULT_PARAMS.with_overrides(**rig), phi0, omega0, until_s - start, STEP_S, drive=drive)
        imu = sample_imu(run, Bno055(fusion_timing=False, seed=seed + k))
        phi = np.stack([twist_angle(imu.quat_wxyz[:, n], rest[n], hinge) for n in range(2)], axis=1)
        phi[:, 0] += slip
        first = 0 if k == 0 else 1  # the shared boundary sample once
        t_all.append(imu.t_s[first:] + start)
        phi_all.append(phi[first:])
        omega_all.append(imu.gyro_rad_s[first:, :, 2])
        phi0, omega0, start = tuple(run.phi_rad[-1]), tuple(run.omega_rad_s[-1]), until_s
    return np.concatenate(t_all), np.concatenate(phi_all), np.concatenate(omega_all)


def _monitor(t_s, phi, omega):
    estimator = RigEstimator(DEFAULT_PARAMS, nodes=Bno055(fusion_timing=False), track=TRACKED)
    estimator.start(t_s[0], [phi[0, 0], phi[0, 1], omega[0, 0], omega[0, 1]])
    monitor = HealthMonitor(estimator)
    alarms = []
    for k in range(1, len(t_s)):
        torque = (_torque(t_s[k] - 0.5 * STEP_S), 0.0)  # held over the step, as the simulation held it
        for node in range(2):
            estimator.update(t_s[k], node, phi[k, node], omega[k, node], torques_n_m=torque)
        alarms += monitor.check()
    return monitor, alarms


def test_each_change_is_alarmed_within_a_minute_on_its_own_parameter():
    paper = DEFAULT_PARAMS
    slip = math.radians(3.0)
    pieces = [
        (15.0, {}, 0.0),
        (30.0, {}, slip),  # M1's node turns by 3 deg on its mount at 15 s
        (45.0, {"c1_n_m": 0.95 * paper.c1_n_m}, slip),  # the coupling springs weaken by 5 % at 30 s
        (75.0, {"c1_n_m": 0.95 * paper.c1_n_m, "b1_n_m_s": 2 * paper.b1_n_m_s}, slip),  # M1's damping doubles at 45 s
    ]
    _, alarms = _monitor(*_measured(pieces, seed=11))
    by_name = {a.parameter: a for a in alarms}
    assert set(by_name) == {"offset_m1_rad", "coupling_sin_n_m", "b1_n_m_s"}, [a.describe() for a in alarms]
    for name, at_s, truth in (
        ("offset_m1_rad", 15.0, slip),
        ("coupling_sin_n_m", 30.0, 2 * 0.95 * paper.c1_n_m * paper.l01_m * paper.l04_m),
        ("b1_n_m_s", 45.0, 2 * paper.b1_n_m_s),
    ):
        alarm = by_name[name]
        assert at_s <= alarm.t_s <= at_s + 30.0  # within the 60 s asked, and before the next change's test ends
        assert at_s - 2.0 <= alarm.since_s <= alarm.t_s
        # by how much: the truth within the alarm's interval, widened for a damping estimate still moving
        assert abs(alarm.value - truth) < 3 * alarm.sigma + 0.5 * abs(truth - alarm.reference), alarm.describe()


def test_a_healthy_rig_raises_no_alarm():
    monitor, alarms = _monitor(*_measured([(60.0, {}, 0.0)], seed=12))
    assert alarms == []
    assert max(monitor.largest_z().values()) < monitor.threshold
