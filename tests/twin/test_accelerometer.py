"""The live twin fuses each node's accelerometer (``RigEstimator.update_accel``): its predicted
reading against MuJoCo's accelerometer sensor, its innovations on the sensor model's data, and a
node that turns on its mount."""

from __future__ import annotations

import math

import numpy as np
import pytest
from emulated_twin import twin_on_nodes

from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.planar_fit import ljung_box_p
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu
from pendsim_mj.twin.estimator import NSTATE, RigEstimator
from pendsim_mj.twin.session import TwinSession
from pendsim_mj.twin.unscented import ACCEL

IMPERFECT = ["--phi1-deg", "31.9", "--heading-deg", "230", "--mount-misalignment-deg", "2", "--fusion-error-deg", "0.2",
             "--hold-wobble-deg", "1", "--loss", "0.02"]  # fmt: skip


def _twin(duration_s: float, args: list[str]) -> TwinSession:
    """``pendsim nodes``'s samples (2 s held, then the release) fed in time order into a twin."""
    return twin_on_nodes(["--duration-s", str(duration_s), "--hold-s", "2", *args])


@pytest.fixture(scope="module")
def truth():
    """20 s of MuJoCo from a 35 deg / -10 deg release (both pendulums swinging), 10 ms steps."""
    return simulate(DEFAULT_PARAMS, (math.radians(35), math.radians(-10)), (0.0, 0.0), 20.0, 0.01)


def _readings(estimator: RigEstimator, states: np.ndarray, node: int) -> np.ndarray:
    """The estimator's predicted reading at each state (k, n), in blocks of its sigma-point count."""
    m = 2 * estimator.n + 1
    out = []
    for a in range(0, len(states), m):
        block = states[a : a + m]
        padded = np.concatenate([block, np.repeat(block[-1:], m - len(block), axis=0)])
        out.append(estimator._readings(ACCEL, padded, node, (0.0, 0.0))[: len(block)])
    return np.concatenate(out)


@pytest.mark.parametrize("node", [0, 1])
def test_the_predicted_reading_is_mujocos_accelerometer_at_the_node(truth, node):
    """The reading the estimator predicts from a state (r alpha + g sin phi, r omega^2 + g cos phi,
    alpha from the fast engine's force law) equals MuJoCo's own accelerometer sensor at the IMU
    site (x tangential, y toward the pivot on the model's mount) over a 35 deg swing."""
    estimator = RigEstimator(DEFAULT_PARAMS)
    states = np.column_stack([truth.phi_rad, truth.omega_rad_s])
    predicted = _readings(estimator, states, node)
    mujoco = truth.imu_accel_m_s2[:, node, :2]
    assert np.ptp(mujoco[:, 0]) > 2.0 and np.ptp(mujoco[:, 1]) > 0.2  # readings that move
    np.testing.assert_allclose(predicted, mujoco, atol=2e-4)  # 1 % of the accelerometer's noise


def test_a_delayed_node_reads_its_accelerometer_that_much_earlier():
    """M2 with a tracked delay d: the predicted reading is MuJoCo's d earlier (first order in d:
    within 2e-3 m/s^2 for d = 2.5 ms, the largest the fusion timing leaves, where ignoring d would
    be off by up to 0.05 m/s^2)."""
    d = 0.0025  # one simulation step
    truth = simulate(DEFAULT_PARAMS, (math.radians(35), math.radians(-10)), (0.0, 0.0), 5.0, d)
    estimator = RigEstimator(DEFAULT_PARAMS, track=("delay_m2_s",))
    states = np.column_stack([truth.phi_rad, truth.omega_rad_s, np.full(len(truth.t_s), d)])
    predicted = _readings(estimator, states, 1)[1:]
    earlier = truth.imu_accel_m_s2[:-1, 1, :2]
    undelayed = truth.imu_accel_m_s2[1:, 1, :2]
    assert np.max(np.abs(undelayed - earlier)) > 0.02
    np.testing.assert_allclose(predicted, earlier, atol=2e-3)


def test_a_turned_accelerometer_reads_gravity_at_the_angle_plus_its_turn(truth):
    """A node whose accelerometer is turned by 3 deg about the hinge (``accel_turn_m1_rad``) reads
    the specific force turned by it: gravity as at phi + 3 deg, the kinematics turned alike."""
    estimator = RigEstimator(DEFAULT_PARAMS, track=("accel_turn_m1_rad",))
    turn = math.radians(3.0)
    states = np.column_stack([truth.phi_rad, truth.omega_rad_s, np.full(len(truth.t_s), turn)])
    predicted = _readings(estimator, states, 0)
    f = truth.imu_accel_m_s2[:, 0, :2]
    c, s = math.cos(turn), math.sin(turn)
    np.testing.assert_allclose(predicted[:, 0], c * f[:, 0] + s * f[:, 1], atol=2e-4)
    np.testing.assert_allclose(predicted[:, 1], c * f[:, 1] - s * f[:, 0], atol=2e-4)
    # at rest (phi = 0, no motion) the tangential reading is g sin(turn)
    rest = _readings(estimator, np.array([[0.0, 0.0, 0.0, 0.0, turn]]), 0)
    assert rest[0, 0] == pytest.approx(DEFAULT_PARAMS.g_m_s2 * math.sin(turn), rel=1e-9)


def test_the_accelerometers_innovations_are_white_with_the_covariance_the_filter_predicts():
    """The sensor model's accelerometer (noise, quantisation) fused after each node's angle and
    rate: its normalised innovations pass Ljung-Box and have unit variance on both axes of both
    nodes, and the angles stay within 0.5 deg of the truth."""
    truth = simulate(DEFAULT_PARAMS, (math.radians(30), 0.0), (0.0, 0.0), 20.0, 0.0125)
    nodes = Bno055(fusion_timing=False, seed=5)
    imu = sample_imu(truth, nodes)
    estimator = RigEstimator(DEFAULT_PARAMS, nodes=nodes)
    omega = imu.gyro_rad_s[:, :, 2]
    phi = truth.phi_rad[: len(imu.t_s)] + 0.0  # the angle channel is not what this test checks
    estimator.start(imu.t_s[0], [phi[0, 0], phi[0, 1], omega[0, 0], omega[0, 1]])
    updates, errors = [], []
    for k in range(1, len(imu.t_s)):
        for node in range(2):
            estimator.update(imu.t_s[k], node, phi[k, node], omega[k, node])
            a = imu.accel_m_s2[k, node]
            updates.append(estimator.update_accel(imu.t_s[k], node, a[0], a[1]))
        errors.append(np.abs(estimator.x[:2] - truth.phi_rad[k]))
    assert np.degrees(np.max(errors[200:])) < 0.5
    for node in range(2):
        nu = np.array([u.innovation / np.sqrt(np.diag(u.covariance)) for u in updates if u.node == node])[200:]
        assert len(nu) > 1000
        for j in range(2):
            assert ljung_box_p(nu[:, j]) > 0.01, (node, j)
            assert 0.85 < np.std(nu[:, j]) < 1.15, (node, j, np.std(nu[:, j]))
            assert abs(np.mean(nu[:, j])) < 0.15, (node, j)


def test_the_twin_on_imperfect_nodes_fuses_both_accelerometers_white_and_finds_their_frames_turn():
    """The whole twin on ``pendsim nodes`` data with every imperfection (heading, 2 deg askew,
    fusion error, wobble, loss): each node's accelerometer is read in its learned frame, whose
    in-plane axes the frame fit leaves about 0.1 deg off (tracked: ``accel_turn``); its mean NIS
    is that of chi^2 with 2 degrees of freedom and its innovations are white."""
    session = _twin(40.0, ["--seed", "0", *IMPERFECT])
    summary = session.summary()
    for node in range(2):
        assert 1.8 < summary.accel_nis_mean[node] < 2.3, summary.accel_nis_mean
        assert min(summary.accel_whiteness_p[node]) > 0.01, summary.accel_whiteness_p
    assert summary.alarms == ()


def test_a_node_turning_on_its_mount_turns_its_accelerometer_with_it():
    """M2's node turns 3 deg on its mount 8 s after the release (``--fault mount:m2=3deg@8``): the
    twin's accelerometer turn for M2 follows by 3 deg (the accelerometer turned with the node) and
    its accelerometer's innovations stay those of a healthy node after it."""
    session = _twin(30.0, ["--seed", "2", "--fault", "mount:m2=3deg@8"])
    summary = session.summary()
    assert [a.parameter for a in summary.alarms] == ["offset_m2_rad"]
    turn = session.estimator.x[NSTATE + session.estimator.track.index("accel_turn_m2_rad")]
    other = session.estimator.x[NSTATE + session.estimator.track.index("accel_turn_m1_rad")]
    assert math.degrees(turn - other) == pytest.approx(3.0, abs=0.3)
    assert 1.7 < summary.accel_nis_mean[1] < 2.5, summary.accel_nis_mean
