"""The BNO055 nodes measured live, a few samples at a time (the emulated rig with motors):
``hinge_readings`` (MuJoCo's IMU sensors in closed form) and ``LiveImu`` (the sensor model's
mount, noise and quantisation, drawn as the samples come)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pendsim_mj.engines.fast_planar.closed_form import accelerations, coefficients
from pendsim_mj.engines.simulation import evaluate_states
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import (
    GYRO_LSB_RAD_S,
    QUAT_LSB,
    Bno055,
    ImuNoise,
    LiveImu,
    hinge_readings,
)
from pendsim_mj.sensors.imperfections import Imperfections


def test_hinge_readings_are_mujoco_s_sensors_to_rounding():
    rng = np.random.default_rng(0)
    phi = rng.uniform(-2.5, 2.5, (40, 2))
    omega = rng.uniform(-6.0, 6.0, (40, 2))
    a1, a2 = accelerations(phi[:, 0], phi[:, 1], omega[:, 0], omega[:, 1], coefficients([DEFAULT_PARAMS])[:, :1])
    mine = hinge_readings(DEFAULT_PARAMS, phi, omega, np.stack([a1, a2], axis=1))
    theirs = evaluate_states(DEFAULT_PARAMS, phi, omega)
    for name in ("imu_accel_m_s2", "imu_gyro_rad_s", "imu_angacc_rad_s2"):
        np.testing.assert_allclose(mine[name], theirs[name], atol=1e-12, err_msg=name)
    dots = np.abs(np.sum(mine["imu_quat_wxyz"] * theirs["imu_quat_wxyz"], axis=-1))  # q and -q: one rotation
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)


def test_live_measurement_without_noise_is_the_ideal_reading():
    live = LiveImu(Bno055(noise=False), DEFAULT_PARAMS.g_m_s2)
    readings = hinge_readings(DEFAULT_PARAMS, np.array([[0.3, -0.1]]), np.array([[1.0, 0.5]]), np.zeros((1, 2)))
    out = live.measure(readings, np.array([0.25]))
    np.testing.assert_array_equal(out.gyro_rad_s, readings["imu_gyro_rad_s"])
    np.testing.assert_array_equal(out.quat_wxyz, readings["imu_quat_wxyz"])
    g = DEFAULT_PARAMS.g_m_s2
    np.testing.assert_allclose(out.gravity_m_s2[0, 0], [g * math.sin(0.3), g * math.cos(0.3), 0.0], atol=1e-12)


def test_live_noise_has_the_model_s_sigma_on_the_chip_s_grid_and_repeats_with_its_seed():
    config = Bno055(seed=4)
    still = hinge_readings(DEFAULT_PARAMS, np.zeros((4000, 2)), np.zeros((4000, 2)), np.zeros((4000, 2)))
    first = LiveImu(config, DEFAULT_PARAMS.g_m_s2)
    parts = [first.measure({k: v[i : i + 2] for k, v in still.items()}, np.zeros(2)) for i in range(0, 4000, 2)]
    gyro = np.concatenate([p.gyro_rad_s for p in parts])
    sigma = np.asarray(ImuNoise().gyro_sigma_rad_s)
    np.testing.assert_allclose(gyro.std(axis=0), np.tile(sigma, (2, 1)), rtol=0.06)
    np.testing.assert_allclose(gyro / GYRO_LSB_RAD_S, np.rint(gyro / GYRO_LSB_RAD_S), atol=1e-9)
    quat = np.concatenate([p.quat_wxyz for p in parts])
    np.testing.assert_allclose(quat / QUAT_LSB, np.rint(quat / QUAT_LSB), atol=1e-6)
    again = LiveImu(config, DEFAULT_PARAMS.g_m_s2).measure({k: v[:2] for k, v in still.items()}, np.zeros(2))
    np.testing.assert_array_equal(again.gyro_rad_s, parts[0].gyro_rad_s)


@pytest.mark.parametrize(
    "config",
    [
        Bno055(imperfections=Imperfections(packet_loss=0.1)),
        Bno055(imperfections=Imperfections(latency_s=0.01)),
        Bno055(imperfections=Imperfections(fusion_error_rad=0.01)),
        Bno055(noise_model=ImuNoise(gyro_bias_instability_rad_s=(1e-4, 1e-4, 1e-4))),
    ],
)
def test_whole_run_processes_cannot_be_drawn_live(config):
    with pytest.raises(ParameterError, match="live node model"):
        LiveImu(config, 9.81)
