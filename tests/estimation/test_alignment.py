"""Alignment on arrays (pendsim_mj.estimation.alignment): angles independent of heading, mount and axis
remap; the start of a run with or without a hold, cut or mid-swing; clocks, fusion timing and
coverage. The truth is the simulated trajectory at the instants each sample's value belongs to."""

import dataclasses
import math
import re

import numpy as np
import pytest

from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.alignment import NodeSamples, align
from pendsim_mj.estimation.timing import fit_clock
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu
from pendsim_mj.sensors.imperfections import Imperfections, all_axis_remaps, axis_remap_matrix, random_mount

HOLD_S = 2.0


@pytest.fixture(scope="module")
def swing():
    return simulate(DEFAULT_PARAMS, (math.pi / 6, 0.0), (0.0, 0.0), 8.0)


def _nodes(imu, *, after_s=None):
    out = []
    for k in range(2):
        stamp, log, received = imu.node_times(k)
        keep = received if after_s is None else received & (log >= after_s)
        values = (imu.quat_wxyz[keep, k], imu.gyro_rad_s[keep, k], imu.accel_m_s2[keep, k])
        out.append(NodeSamples(log[keep], *values, stamp_s=stamp[keep]))
    return out


def _truth(traj, imu, run, k, hold_s=0.0):
    """The simulated phi of node k at the true instants of the values the run kept."""
    value_t = (imu.value_t_s[:, k] if imu.value_t_s is not None else imu.fused_t_s)[_kept(imu, k)]
    t = value_t[len(value_t) - len(run.nodes[k].t_s) :] - hold_s
    inside = np.interp(np.clip(t, 0.0, None), traj.t_s, traj.phi_rad[:, k])
    return np.where(t < 0, traj.phi_rad[0, k], inside)


def _kept(imu, k):
    return imu.node_times(k)[2]


def test_angles_hold_to_0_1_deg_for_every_axis_remap_any_heading_and_a_10_deg_mount(swing):
    rng = np.random.default_rng(11)
    worst = 0.0
    for i, (config, sign) in enumerate(all_axis_remaps()):
        heading = float(rng.uniform(-math.pi, math.pi))
        imperfect = Imperfections(heading_rad=heading, axis_map_config=(config, config), axis_map_sign=(sign, sign))
        mounts = (random_mount(math.radians(10), rng), random_mount(math.radians(10), rng))
        imu = sample_imu(swing, Bno055(seed=i, mount_quat_wxyz=mounts, imperfections=imperfect))
        run = align(_nodes(imu), DEFAULT_PARAMS)
        for k in range(2):
            error = np.abs(run.nodes[k].phi_rad - _truth(swing, imu, run, k))
            worst = max(worst, float(np.degrees(error.max())))
        mirrored = bool(np.linalg.det(axis_remap_matrix(config, sign)) < 0)
        assert [n.frame.mirrored for n in run.nodes] == [mirrored, mirrored]
    assert worst < 0.1


def test_a_recording_that_starts_at_the_release_starts_in_motion_from_the_release_state(swing):
    imu = sample_imu(swing, Bno055(seed=1))
    run = align(_nodes(imu), DEFAULT_PARAMS)
    assert run.start.kind == "in motion" and run.start.time_s == 0.0
    assert math.degrees(run.start.phi_rad[0]) == pytest.approx(30.0, abs=0.1)
    assert max(abs(w) for w in run.start.omega_rad_s) < 0.05  # at rest, within the fusion timing's half step
    assert run.nodes[0].frame.radius_m == pytest.approx(DEFAULT_PARAMS.om1_m, abs=0.005)
    # the first sample's fused value is older than the start: left out, and counted as such
    for node in run.nodes:
        assert node.before_start == 1 and node.value_t_s[0] >= 0
        assert len(node.t_s) + node.before_start == len(imu.t_s)


def test_a_hold_with_hand_wobble_is_found_as_a_release_from_rest(swing):
    wobble = Imperfections(hold_wobble_rad=math.radians(0.2))
    imu = sample_imu(swing, Bno055(seed=2, imperfections=wobble), hold_s=HOLD_S)
    run = align(_nodes(imu), DEFAULT_PARAMS)
    assert run.start.kind == "release"
    assert run.start.time_s == pytest.approx(HOLD_S, abs=0.005)
    np.testing.assert_allclose(np.degrees(run.start.phi_rad), [30.0, 0.0], atol=0.1)
    assert run.start.omega_rad_s == (0.0, 0.0)


@pytest.mark.parametrize("wobble_deg", [0.0, 0.5, 1.0, 2.0])
def test_a_release_after_a_hold_with_hand_wobble_is_found_to_a_sample_and_0_3_deg(swing, wobble_deg):
    # hand drift and tremor of up to 2 deg rms while held: the release is the foot of the large
    # swing, not the first departure from the hold's noise band; M1's release angle is positive
    for seed in range(3):
        imperfect = Imperfections(hold_wobble_rad=math.radians(wobble_deg))
        imu = sample_imu(swing, Bno055(seed=10 + seed, imperfections=imperfect), hold_s=HOLD_S)
        run = align(_nodes(imu), DEFAULT_PARAMS)
        sample_s = 1.0 / Bno055().sample_rate_hz
        assert run.start.kind == "release"
        assert run.start.time_s == pytest.approx(HOLD_S, abs=sample_s)
        np.testing.assert_allclose(np.degrees(run.start.phi_rad), [30.0, 0.0], atol=0.3)
        assert not run.start.poor_fit and run.start.fit_note() == ""


def test_a_found_start_whose_following_motion_is_no_release_is_refused_naming_release_s(swing):
    # a knock on M1's sensor while held: a burst of gyro rate, the angles do not move
    imu = sample_imu(swing, Bno055(seed=6), hold_s=HOLD_S)
    m1, m2 = _nodes(imu)
    gyro = m1.gyro_rad_s.copy()
    i = int(np.searchsorted(m1.log_t_s, 1.0))
    gyro[i : i + 4, 2] += 4.0
    knocked = NodeSamples(m1.log_t_s, m1.quat_wxyz, gyro, m1.accel_m_s2, stamp_s=m1.stamp_s)
    with pytest.raises(RecordingError, match=r"^the release from rest found at 0\.9\d\d s .*--release-s"):
        align((knocked, m2), DEFAULT_PARAMS)
    run = align((knocked, m2), DEFAULT_PARAMS, release_s=HOLD_S - 0.01)  # the way out the message names
    assert run.start.kind == "given" and not run.start.poor_fit


def test_a_model_that_does_not_explain_the_first_second_is_reported_as_a_poor_fit(swing):
    imu = sample_imu(swing, Bno055(seed=7), hold_s=HOLD_S)
    good = align(_nodes(imu), DEFAULT_PARAMS, release_s=HOLD_S)
    assert good.start.unexplained < 0.01 and not good.start.poor_fit
    wrong = dataclasses.replace(DEFAULT_PARAMS, g_m_s2=1.5 * DEFAULT_PARAMS.g_m_s2)  # frequencies 22 % high
    poor = align(_nodes(imu), wrong, release_s=HOLD_S)
    assert poor.start.poor_fit
    assert re.fullmatch(
        r"poor start fit: the model leaves \d+ % of the motion over the first 1 s unexplained; .*",
        poor.start.fit_note(),
    )


def test_a_cut_mid_swing_starts_from_the_state_at_its_first_samples(swing):
    imu = sample_imu(swing, Bno055(seed=3))
    run = align(_nodes(imu, after_s=6.0), DEFAULT_PARAMS)
    assert run.start.kind == "in motion" and run.start.time_s == pytest.approx(6.0, abs=1e-9)
    # the state there: the trajectory's, up to the fusion timing's common shift (under 1.25 ms)
    # and the mirror image M1's sign convention may choose (the rig is symmetric)
    i = round(6.0 / swing.dt_s)
    sign = np.sign(run.start.phi_rad[0] / swing.phi_rad[i, 0])
    slack = np.abs(swing.omega_rad_s[i]) * 0.00125 + np.radians(0.1)
    assert np.all(np.abs(sign * np.array(run.start.phi_rad) - swing.phi_rad[i]) < slack)
    assert np.all(np.abs(sign * np.array(run.start.omega_rad_s) - swing.omega_rad_s[i]) < 0.1)
    for k in range(2):
        assert np.max(np.abs(sign * run.nodes[k].phi_rad - _truth(swing, imu, run, k))) < math.radians(0.1)


def test_a_given_start_overrides_the_detection(swing):
    imu = sample_imu(swing, Bno055(seed=4), hold_s=HOLD_S)
    run = align(_nodes(imu), DEFAULT_PARAMS, release_s=3.0)
    assert run.start.kind == "given" and run.start.time_s == 3.0
    assert all(n.value_t_s[0] >= 0 for n in run.nodes)
    with pytest.raises(ParameterError, match=r"release_s = 99.0 s is outside the samples of both nodes"):
        align(_nodes(imu), DEFAULT_PARAMS, release_s=99.0)


def test_no_motion_is_a_clear_error():
    still = simulate(DEFAULT_PARAMS, (0.0, 0.0), (0.0, 0.0), 5.0)
    imu = sample_imu(still, Bno055(seed=5))
    with pytest.raises(RecordingError, match=r"^no motion found: both gyros stay below 0.05 rad/s"):
        align(_nodes(imu), DEFAULT_PARAMS)


def test_drifting_clocks_lost_packets_and_fusion_phases_are_aligned_to_where_values_belong(swing):
    imperfect = Imperfections(
        clock_drift_ppm=(0.0, 50.0),
        clock_offset_s=(0.0, 40.0),
        packet_loss=0.05,
        loss_burst_samples=4,
        latency_s=0.002,
        fusion_phase_s=(0.0037, 0.0081),
    )
    imu = sample_imu(swing, Bno055(seed=6, imperfections=imperfect))
    run = align(_nodes(imu), DEFAULT_PARAMS)
    for k in range(2):
        node = run.nodes[k]
        true_t = imu.value_t_s[_kept(imu, k), k][-len(node.t_s) :]
        error_ms = 1000 * (node.value_t_s + run.start.time_s - true_t)
        # the pattern of fusion ages is found exactly; the common part within an eighth of the
        # 10 ms fusion period (the start fit absorbs it)
        assert np.ptp(error_ms) < 0.05 and abs(np.mean(error_ms)) <= 1.25 + 0.05
        assert np.max(np.abs(node.phi_rad - _truth(swing, imu, run, k))) < math.radians(0.1)
        covered = np.diff(node.t_s)[np.diff(node.t_s) <= run.max_gap_s].sum()
        assert node.coverage.covered_fraction == pytest.approx(covered / (node.t_s[-1] - node.t_s[0]))
        assert node.coverage.lost_fraction == pytest.approx(1 - imu.received[:, k].mean(), abs=0.01)
    assert run.nodes[1].clock.drift_ppm == pytest.approx(50.0, abs=5.0)


def test_the_clock_fit_lies_under_the_latency_and_finds_the_drift():
    rng = np.random.default_rng(7)
    stamp = 1000.0 + np.arange(9600) / 80.0  # 120 s on a node clock 1000 s ahead
    true_rate = 1 / (1 + 50e-6)
    log = (stamp - 1000.0) * true_rate + rng.exponential(0.002, len(stamp))
    clock = fit_clock(stamp, log)
    assert clock is not None
    assert clock.drift_ppm == pytest.approx(50.0, abs=0.5)
    residual = log - clock.to_recorder(stamp)
    assert residual.min() >= -1e-9 and residual.min() < 1e-4  # under every point, touching the least delayed
    assert fit_clock(stamp, stamp * 1.5) is None  # not a clock of the recorder's
