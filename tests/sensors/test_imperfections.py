"""The imperfections of real nodes in the sensor model: axis remap by the datasheet's registers,
NDOF heading, fusion error, bursty packet loss, drifting clocks, hand wobble; all seeded and off
by default."""

import math

import numpy as np
import pytest

from pendsim_bridge.io.recording import RunInfo, read_recording, write_recording
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.timing import fit_clock
from pendsim_mj.rig.model import exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors import imperfections as imp
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import Bno055, sample_imu
from pendsim_mj.sensors.imperfections import Imperfections, all_axis_remaps, axis_remap_matrix, gilbert_loss

IDEAL = Bno055(noise=False)


@pytest.fixture(scope="module")
def swing():
    return simulate(DEFAULT_PARAMS, (math.pi / 6, 0.0), (0.0, 0.0), 6.0)


def test_the_datasheet_registers_pick_and_negate_source_axes():
    # BNO055 datasheet rev 1.4, 3.4: AXIS_MAP_CONFIG bits 1-0 name the source of x, 3-2 of y,
    # 5-4 of z (0 x, 1 y, 2 z); AXIS_MAP_SIGN bit 2 negates x, bit 1 y, bit 0 z.
    np.testing.assert_array_equal(axis_remap_matrix(0x24, 0x00), np.eye(3))
    v = np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(axis_remap_matrix(0x21, 0x00) @ v, [2.0, 1.0, 3.0])  # x <- y, y <- x
    np.testing.assert_array_equal(axis_remap_matrix(0x24, 0x04) @ v, [-1.0, 2.0, 3.0])  # x negated
    np.testing.assert_array_equal(axis_remap_matrix(0x24, 0x01) @ v, [1.0, 2.0, -3.0])  # z negated
    np.testing.assert_array_equal(axis_remap_matrix(0x06, 0x00) @ v, [3.0, 2.0, 1.0])  # x <- z, z <- x
    remaps = all_axis_remaps()
    assert len(set(remaps)) == 48
    dets = [np.linalg.det(axis_remap_matrix(c, s)) for c, s in remaps]
    assert sorted(np.rint(dets)) == [-1.0] * 24 + [1.0] * 24  # 24 rotations, 24 mirrorings


@pytest.mark.parametrize(
    ("config", "sign", "message"),
    [
        (0x25, 0x00, "does not name each of x, y, z once"),
        (0x3F, 0x00, "does not name each of x, y, z once"),
        (0x24, 0x08, "AXIS_MAP_SIGN must be 0x00-0x07"),
        (0x40, 0x00, "AXIS_MAP_CONFIG must be a byte 0x00-0x3F"),
    ],
)
def test_registers_the_chip_refuses_are_refused(config, sign, message):
    with pytest.raises(ParameterError, match=message):
        Imperfections(axis_map_config=(config, 0x24), axis_map_sign=(sign, 0))


def test_a_remap_permutes_every_vector_output_and_keeps_the_orientation_consistent(swing):
    plain = sample_imu(swing, IDEAL)
    remap = Imperfections(axis_map_config=(0x09, 0x09), axis_map_sign=(0x03, 0x03))  # x <- y, y <- z, z <- x
    mapped = sample_imu(swing, Bno055(noise=False, imperfections=remap))
    p = axis_remap_matrix(0x09, 0x03)
    assert np.linalg.det(p) > 0
    for name in ("accel_m_s2", "gyro_rad_s", "gravity_m_s2", "linear_accel_m_s2"):
        np.testing.assert_allclose(getattr(mapped, name), getattr(plain, name) @ p.T, atol=1e-12, err_msg=name)
    # a proper remap: the quaternion describes the remapped axes, R' = R P^T
    np.testing.assert_allclose(
        rotations.to_matrix(mapped.quat_wxyz), rotations.to_matrix(plain.quat_wxyz) @ p.T, atol=1e-12
    )


def test_a_mirroring_remap_reports_the_orientation_of_the_reversed_right_handed_frame(swing):
    plain = sample_imu(swing, IDEAL)
    mapped = sample_imu(swing, Bno055(noise=False, imperfections=Imperfections(axis_map_sign=(0x01, 0x01))))
    p = axis_remap_matrix(0x24, 0x01)
    np.testing.assert_allclose(mapped.gyro_rad_s, plain.gyro_rad_s @ p.T, atol=1e-12)
    np.testing.assert_allclose(
        rotations.to_matrix(mapped.quat_wxyz), rotations.to_matrix(plain.quat_wxyz) @ (-p).T, atol=1e-12
    )


def test_the_ndof_heading_turns_only_the_orientations_world_frame(swing):
    plain = sample_imu(swing, IDEAL)
    heading = math.radians(60)
    turned = sample_imu(swing, Bno055(noise=False, imperfections=Imperfections(heading_rad=heading)))
    for name in ("accel_m_s2", "gyro_rad_s", "gravity_m_s2"):
        np.testing.assert_array_equal(getattr(turned, name), getattr(plain, name))
    c, s = math.cos(heading), math.sin(heading)
    world_to_north = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # the world seen from the turned frame
    np.testing.assert_allclose(
        rotations.to_matrix(turned.quat_wxyz), world_to_north @ rotations.to_matrix(plain.quat_wxyz), atol=1e-12
    )


def test_the_fusion_error_is_a_slowly_varying_small_angle_of_the_configured_size(swing):
    long_run = simulate(DEFAULT_PARAMS, (0.0, 0.0), (0.0, 0.0), 600.0)
    rms = math.radians(0.5)
    plain = sample_imu(long_run, IDEAL)
    erred = sample_imu(long_run, Bno055(noise=False, imperfections=Imperfections(fusion_error_rad=rms)))
    rel = rotations.multiply(rotations.conjugate(plain.quat_wxyz), erred.quat_wxyz)
    angle = 2 * np.arcsin(np.clip(np.linalg.norm(rel[..., 1:], axis=-1), 0, 1))
    # three independent axes of rms 0.5 deg: the rotation angle has rms sqrt(3) x 0.5 deg
    assert math.sqrt(np.mean(angle**2)) == pytest.approx(math.sqrt(3) * rms, rel=0.25)
    # slow: it keeps its value over a second and forgets it over a minute (periods 10-90 s)
    lag = round(80 * 1.0)
    a = angle - angle.mean(axis=0)
    assert np.mean(a[:-lag] * a[lag:]) / np.mean(a * a) > 0.8
    lag = round(80 * 60.0)
    assert np.mean(a[:-lag] * a[lag:]) / np.mean(a * a) < 0.5
    # the gravity output follows the erroneous orientation (the chip derives it from its estimate)
    np.testing.assert_allclose(
        erred.gravity_m_s2, rotations.rotate_into_frame(erred.quat_wxyz, np.array([0, 0, 9.81])), atol=1e-12
    )


def test_packet_loss_has_the_configured_share_and_burst_length():
    rng = np.random.default_rng(1)
    received = gilbert_loss(rng, 400_000, 0.05, 4.0)
    lost = ~received
    assert lost.mean() == pytest.approx(0.05, rel=0.05)
    starts = np.flatnonzero(lost[1:] & ~lost[:-1])
    ends = np.flatnonzero(~lost[1:] & lost[:-1])
    bursts = ends[ends > starts[0]][: len(starts) - 1] - starts[: len(starts) - 1]
    assert bursts.mean() == pytest.approx(4.0, rel=0.05)


def test_lost_packets_and_drifting_stamps_reach_the_recording(swing, tmp_path):
    drift = 50.0
    imperfect = Imperfections(
        packet_loss=0.05, loss_burst_samples=3, clock_drift_ppm=(0.0, drift), clock_offset_s=(0.0, 12.0),
        latency_s=0.002,
    )  # fmt: skip
    imu = sample_imu(swing, Bno055(seed=2, imperfections=imperfect))
    path = write_recording(
        tmp_path / "lossy.mcap",
        imu,
        RunInfo("mujoco", (math.pi / 6, 0.0), (0.0, 0.0), 6.0, 0.01),
        exact_mjcf(DEFAULT_PARAMS),
        DEFAULT_PARAMS,
        traj=swing,
    )
    rec = read_recording(path)
    assert rec.imu_config().imperfections == imperfect  # the metadata carries them
    for k, node in enumerate(("m1", "m2")):
        topic = rec.imu[node]
        assert len(topic.t_ns) == int(imu.received[:, k].sum()) < len(imu.t_s)
        assert np.all(np.diff(topic.t_ns) >= 0)
    m2 = rec.imu["m2"]
    # header stamps: M2's own clock (12 s ahead, 50 ppm fast); log times: the recorder's
    clock = fit_clock(m2.stamp_ns * 1e-9, m2.t_ns * 1e-9)
    assert clock is not None
    assert clock.drift_ppm == pytest.approx(drift, abs=5.0)  # 5 ppm over 6 s: 30 us
    assert clock.to_recorder(0.0) == pytest.approx(-12.0 / (1 + drift * 1e-6), abs=2e-4)  # stamp 0 maps to -12 s


def test_hand_wobble_moves_the_held_pendulums_and_fades_out_before_the_release(swing):
    wobble = math.radians(0.2)
    imu = sample_imu(swing, Bno055(noise=False, imperfections=Imperfections(hold_wobble_rad=wobble)), hold_s=3.0)
    held = imu.t_s < 3.0
    angle = np.arctan2(imu.gravity_m_s2[held, 0, 0], imu.gravity_m_s2[held, 0, 1])
    early = imu.t_s[held] < 2.4
    assert np.std(angle[early]) == pytest.approx(wobble, rel=0.5)
    assert np.abs(imu.gyro_rad_s[held, 0, 2][-3:]).max() < 0.01  # still at the release
    assert abs(angle[-1] - math.pi / 6) < 1e-4


def test_imperfections_are_seeded_and_off_by_default(swing):
    noisy = Imperfections(packet_loss=0.1, fusion_error_rad=0.01, clock_drift_ppm=(0, 20), latency_s=0.001)
    a, b = (sample_imu(swing, Bno055(seed=9, imperfections=noisy)) for _ in range(2))
    np.testing.assert_array_equal(a.received, b.received)
    np.testing.assert_array_equal(a.quat_wxyz, b.quat_wxyz)
    np.testing.assert_array_equal(a.log_t_s, b.log_t_s)
    plain = sample_imu(swing, Bno055())
    assert plain.received is None and plain.stamp_s is None and plain.log_t_s is None
    np.testing.assert_allclose(plain.fused_t_s * 100, np.rint(plain.fused_t_s * 100), atol=1e-9)  # fusion grid


def test_hand_wobble_is_a_slow_drift_with_a_small_8_to_12_hz_tremor_and_slow_rates():
    # the process itself, over a long hold (t < -WOBBLE_FADE_S: not faded), against its spectrum
    rms = math.radians(2.0)
    rate_hz = 200.0
    t = np.arange(-200.0, -imp.WOBBLE_FADE_S, 1 / rate_hz)
    for seed in range(3):
        angle, rate, _ = imp.hold_wobble(np.random.default_rng(seed), t, rms)
        power = np.abs(np.fft.rfft(angle[:, 0])) ** 2
        f = np.fft.rfftfreq(len(t), 1 / rate_hz)
        share = {
            band: power[(f >= band[0]) & (f <= band[1])].sum() / power[1:].sum() for band in ((0.05, 2.5), (8, 12))
        }
        assert share[(0.05, 2.5)] > 0.99
        assert math.sqrt(share[(8, 12)]) == pytest.approx(imp.TREMOR_SHARE, rel=0.3)
        assert np.std(angle) == pytest.approx(rms, rel=0.3)
        assert np.sqrt(np.mean(rate**2)) < 0.3  # rad/s: a tenth of a 30 deg swing's 2.7 rad/s peak
