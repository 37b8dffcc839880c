"""The simulated BNO055 nodes: timing, ideal kinematics, noise statistics, mount, limits."""

import math

import numpy as np
import pytest

from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import (
    ACCEL_LSB_M_S2,
    GYRO_LSB_RAD_S,
    QUAT_LSB,
    STANDARD_GRAVITY_M_S2,
    Bno055,
    ImuNoise,
    sample_imu,
)

IDEAL = Bno055(noise=False)
RADII = np.array([DEFAULT_PARAMS.om1_m, DEFAULT_PARAMS.om2_m])


@pytest.fixture(scope="module")
def swing():
    return simulate(DEFAULT_PARAMS, (math.pi / 6, 0.0), (0.0, 0.0), 10.0)


@pytest.fixture(scope="module")
def at_rest():
    return simulate(DEFAULT_PARAMS, (0.0, 0.0), (0.0, 0.0), 600.0)


def _rows(traj, fused_t_s):
    return np.rint(fused_t_s / traj.dt_s).astype(int)


def test_samples_are_at_exactly_k_over_80_s(swing):
    s = sample_imu(swing, IDEAL)
    assert len(s.t_s) == 801
    np.testing.assert_array_equal(s.t_s, np.arange(801) / 80.0)


def test_fusion_timing_reads_the_latest_100_hz_value_and_skips_one_in_five(swing):
    s = sample_imu(swing, IDEAL)
    age = s.t_s - s.fused_t_s
    assert age.min() >= 0.0 and age.max() < 0.010
    np.testing.assert_allclose(s.fused_t_s * 100, np.rint(s.fused_t_s * 100), atol=1e-9)  # on the 100 Hz grid
    fused_values = 1001  # 10 s at 100 Hz
    read = len(np.unique(np.rint(s.fused_t_s * 100)))
    assert read == 801 and (fused_values - read) / fused_values == pytest.approx(0.2, abs=0.001)


def test_ideal_tangential_and_normal_accelerations_follow_the_pendulum_kinematics(swing):
    # spec section 6: linear tangential r phi'', accelerometer normal r phi'^2 + g cos phi
    for config in (IDEAL, Bno055(noise=False, fusion_timing=False)):
        s = sample_imu(swing, config)
        if config.fusion_timing:
            rows = _rows(swing, s.fused_t_s)
            phi, omega, alpha = swing.phi_rad[rows], swing.omega_rad_s[rows], swing.alpha_rad_s2[rows]
        else:  # instants between steps: the kinematics of the state at that instant
            phi = np.arctan2(s.gravity_m_s2[..., 0], s.gravity_m_s2[..., 1])
            omega = s.gyro_rad_s[..., 2]
            alpha = None
        g = DEFAULT_PARAMS.g_m_s2
        np.testing.assert_allclose(s.normal_m_s2, RADII * omega**2 + g * np.cos(phi), atol=1e-9)
        np.testing.assert_allclose(s.normal_linear_m_s2, RADII * omega**2, atol=1e-9)
        if alpha is not None:
            np.testing.assert_allclose(s.tangential_linear_m_s2, RADII * alpha, atol=1e-9)
            np.testing.assert_allclose(s.tangential_m_s2, RADII * alpha + g * np.sin(phi), atol=1e-9)


def test_ideal_timing_between_steps_matches_a_run_with_a_finer_step(swing):
    # At 1.25 ms every k/80 s instant is a step: no interpolation. The 10 ms run's interpolated
    # samples must be as close to it as its on-grid samples are (the RK4 error of the 10 ms step).
    config = Bno055(noise=False, fusion_timing=False)
    coarse = sample_imu(swing, config)
    fine = sample_imu(simulate(DEFAULT_PARAMS, (math.pi / 6, 0.0), (0.0, 0.0), 10.0, 0.00125), config)
    on_grid = np.arange(len(coarse.t_s)) % 4 == 0  # k/80 s is a multiple of 10 ms every 4th sample
    for name in ("accel_m_s2", "gyro_rad_s", "quat_wxyz"):
        err = np.abs(getattr(coarse, name) - getattr(fine, name))
        grid_err = err[on_grid].max()
        assert err[~on_grid].max() < 1.5 * grid_err + 1e-9, name
        assert err.max() < 1e-4, name


def test_at_rest_the_accelerometer_reads_plus_g_on_y_within_noise(at_rest):
    s = sample_imu(at_rest, Bno055(seed=1))
    sigma = np.array(ImuNoise().accel_sigma_m_s2)
    expected = np.array([0.0, DEFAULT_PARAMS.g_m_s2, 0.0])
    assert np.all(np.abs(s.accel_m_s2 - expected) <= 6 * sigma + ACCEL_LSB_M_S2)
    standard_error = sigma / math.sqrt(len(s.t_s))
    assert np.all(np.abs(s.accel_m_s2.mean(axis=0) - expected) < 5 * standard_error + ACCEL_LSB_M_S2 / 2)


def test_noise_standard_deviation_per_axis_matches_the_configured_sigma(at_rest):
    s = sample_imu(at_rest, Bno055(seed=2))  # 10 min at 80 Hz: 48 001 samples per axis
    noise = ImuNoise()
    for measured, sigma in ((s.accel_m_s2, noise.accel_sigma_m_s2), (s.gyro_rad_s, noise.gyro_sigma_rad_s)):
        std = measured.std(axis=0)  # (2 nodes, 3 axes), quantisation included
        np.testing.assert_allclose(std, np.tile(sigma, (2, 1)), rtol=0.05)


def test_outputs_are_quantised_to_the_chips_resolution(swing):
    s = sample_imu(swing, Bno055())
    for values, lsb in (
        (s.accel_m_s2, ACCEL_LSB_M_S2),
        (s.linear_accel_m_s2, ACCEL_LSB_M_S2),
        (s.gravity_m_s2, ACCEL_LSB_M_S2),
        (s.gyro_rad_s, GYRO_LSB_RAD_S),
        (s.quat_wxyz, QUAT_LSB),
    ):
        np.testing.assert_allclose(values / lsb, np.rint(values / lsb), atol=1e-6)


def test_accelerometer_clips_at_plus_minus_4_g():
    fast = simulate(DEFAULT_PARAMS, (0.0, 0.0), (15.0, 0.0), 1.0)  # r omega^2 ~ 0.417 * 225 = 94 m/s^2
    ideal = sample_imu(fast, IDEAL)
    measured = sample_imu(fast, Bno055())
    assert ideal.accel_m_s2.max() > 60
    assert measured.accel_m_s2.max() == pytest.approx(4 * STANDARD_GRAVITY_M_S2, abs=ACCEL_LSB_M_S2)
    assert measured.accel_m_s2.min() >= -4 * STANDARD_GRAVITY_M_S2 - ACCEL_LSB_M_S2


def test_a_mount_closer_to_the_pivot_reads_the_acceleration_of_that_radius(swing):
    # Move both nodes 100 mm toward the pivot (sensor +y): tangential linear = (r - 0.1) phi''.
    s = sample_imu(swing, Bno055(noise=False, mount_offset_m=((0, 0.1, 0), (0, 0.1, 0))))
    rows = _rows(swing, s.fused_t_s)
    np.testing.assert_allclose(s.tangential_linear_m_s2, (RADII - 0.1) * swing.alpha_rad_s2[rows], atol=1e-9)
    np.testing.assert_allclose(s.normal_linear_m_s2, (RADII - 0.1) * swing.omega_rad_s[rows] ** 2, atol=1e-9)


def test_a_mount_turned_90_deg_about_z_swaps_x_and_y(swing):
    q = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
    turned = sample_imu(swing, Bno055(noise=False, mount_quat_wxyz=(q, q)))
    plain = sample_imu(swing, IDEAL)
    # new x = old y, new y = -old x
    np.testing.assert_allclose(turned.accel_m_s2[..., 0], plain.accel_m_s2[..., 1], atol=1e-12)
    np.testing.assert_allclose(turned.accel_m_s2[..., 1], -plain.accel_m_s2[..., 0], atol=1e-12)
    np.testing.assert_allclose(turned.gravity_m_s2[..., 0], plain.gravity_m_s2[..., 1], atol=1e-12)


def test_bias_and_bias_random_walk_follow_their_configured_sizes(at_rest):
    walk = 0.002  # m/s^2/sqrt(s)
    noise = ImuNoise(
        accel_sigma_m_s2=(0, 0, 0), accel_bias_m_s2=(0.5, 0, 0), accel_bias_walk_m_s2_per_sqrt_s=(walk,) * 3
    )
    s = sample_imu(at_rest, Bno055(noise_model=noise, seed=3))
    x = s.accel_m_s2[..., 0]
    assert abs(x[0, 0] - 0.5) < ACCEL_LSB_M_S2  # the bias, before the walk has moved
    # increments over 10 s have std walk * sqrt(10 s) (quantisation adds LSB^2/6)
    lag = 800
    inc = (x[lag:] - x[:-lag])[::lag]
    expected = math.sqrt(walk**2 * 10 + ACCEL_LSB_M_S2**2 / 6)
    assert inc.std() == pytest.approx(expected, rel=0.15)


def test_the_same_seed_gives_the_same_samples_and_another_seed_does_not(swing):
    a, b, c = (sample_imu(swing, Bno055(seed=s)) for s in (7, 7, 8))
    np.testing.assert_array_equal(a.accel_m_s2, b.accel_m_s2)
    assert not np.array_equal(a.accel_m_s2, c.accel_m_s2)


def test_calibration_status_travels_with_every_sample(swing):
    s = sample_imu(swing, Bno055(calibration=(2, 3, 3, 1)))
    assert s.calibration.shape == (801, 2, 4) and s.calibration.dtype == np.uint8
    assert np.all(s.calibration == [2, 3, 3, 1])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"sample_rate_hz": 0.0}, "sample_rate_hz must be a finite number > 0"),
        ({"calibration": (4, 3, 3, 3)}, "calibration must be four levels 0-3"),
        ({"mount_quat_wxyz": ((2, 0, 0, 0), (1, 0, 0, 0))}, "must be two unit quaternions"),
    ],
)
def test_bad_configuration_is_rejected(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        Bno055(**kwargs)


def test_negative_noise_sigma_is_rejected():
    with pytest.raises(ParameterError, match=r"accel_sigma_m_s2 must be >= 0, got \(-1.0, 0.0, 0.0\)"):
        ImuNoise(accel_sigma_m_s2=(-1.0, 0.0, 0.0))
