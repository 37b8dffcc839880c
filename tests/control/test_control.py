"""The control room: plants against the engines, the linearised rig against finite differences of
the reference, the LQR design against python-control, and what each controller achieves on the
nonlinear rig (issue 26's targets), each against an independent computation."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from scipy.signal import cont2discrete

from pendsim_mj.control.controllers import (
    LQR,
    BeatingSuppressor,
    EnergyRegulator,
    OpenLoop,
    ScheduledLQR,
    check_stabilising,
)
from pendsim_mj.control.linear import decay_time_s, linearise
from pendsim_mj.control.loop import closed_loop
from pendsim_mj.control.observe import NodeObserver
from pendsim_mj.control.plant import FastPlant, MujocoPlant, replay_drive
from pendsim_mj.engines import reference
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import Sampling, Target
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055
from pendsim_mj.sensors.imperfections import Imperfections

RELEASE_30 = (math.radians(30.0), 0.0)  # M1 released at 30 deg, M2 at rest: both modes excited


def _random_torques(nstep: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u = np.zeros((nstep, 4))
    u[:, 0] = 0.04 * np.sin(0.07 * np.arange(nstep)) + 0.01 * rng.standard_normal(nstep)
    u[:, 1] = 0.02 * rng.standard_normal(nstep)
    return u


def test_both_plants_equal_the_reference_solver_driven_by_the_same_held_torques():
    u = _random_torques(400, seed=1)
    drive = replay_drive(u, 0.01)
    # the independent planar reference (numpy, its own force law) under held inputs
    ref = reference.solve(DEFAULT_PARAMS, (0.5, 0.1), (0.0, 0.0), 4.0, 0.01, drive=drive, sampling=Sampling.HELD)
    for plant in (FastPlant(DEFAULT_PARAMS), MujocoPlant(DEFAULT_PARAMS)):
        states = [plant.reset((0.5, 0.1))[0]]
        states += [plant.step(u[k])[0] for k in range(len(u))]
        x = np.array(states)
        assert np.max(np.abs(x[:, :2] - ref.phi_rad)) < 1e-11, type(plant).__name__
        assert np.max(np.abs(x[:, 2:] - ref.omega_rad_s)) < 1e-10, type(plant).__name__


def test_a_batch_plant_steps_each_member_as_a_plant_of_its_own():
    u = _random_torques(50, seed=2)
    batch = FastPlant(DEFAULT_PARAMS, nenv=3)
    starts = np.array([[0.1, 0.0], [0.5, -0.2], [-1.0, 0.3]])
    batch.reset(starts)
    for k in range(50):
        batch.step(np.stack([u[k], -u[k], 0.5 * u[k]]))
    for i, scale in enumerate((1.0, -1.0, 0.5)):
        single = FastPlant(DEFAULT_PARAMS)
        single.reset(starts[i])
        for k in range(50):
            single.step(scale * u[k])
        np.testing.assert_array_equal(single.state[0], batch.state[i])


def test_the_linearised_rig_equals_central_differences_of_the_reference_equations():
    lin = linearise(DEFAULT_PARAMS)
    k = reference._coefficients([DEFAULT_PARAMS])
    eps = 1e-6

    def rates(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        y = np.concatenate([x, [0.0]])[:, None]
        return reference.derivative(y, k, u[:, None])[:4, 0]

    a = np.zeros((4, 4))
    b = np.zeros((4, 4))
    for j in range(4):
        dx = np.zeros(4)
        dx[j] = eps
        a[:, j] = (rates(dx, np.zeros(4)) - rates(-dx, np.zeros(4))) / (2 * eps)
        b[:, j] = (rates(np.zeros(4), dx) - rates(np.zeros(4), -dx)) / (2 * eps)
    np.testing.assert_allclose(lin.a, a, atol=1e-7)
    np.testing.assert_allclose(lin.b, b, atol=1e-7)


def test_the_held_input_discretisation_equals_scipys_zero_order_hold():
    lin = linearise(DEFAULT_PARAMS)
    channels = (Target.TORQUE_M1, Target.TORQUE_M2, Target.SUPPORT_X)
    a_d, b_d = lin.discrete(0.01, channels)
    ref_a, ref_b, *_ = cont2discrete((lin.a, lin.inputs(channels), np.eye(4), np.zeros((4, 3))), 0.01, "zoh")
    np.testing.assert_allclose(a_d, ref_a, atol=1e-13)
    np.testing.assert_allclose(b_d, ref_b, atol=1e-13)


def test_the_lqr_gain_equals_python_controls_discrete_design():
    controller = LQR(DEFAULT_PARAMS, input_weight=3.0)
    a_d, b_d = controller.linear.discrete(0.01, controller.channels)
    gain, _, _ = ct.dlqr(a_d, b_d, controller.linear.energy_weight, 3.0 * np.eye(2))
    np.testing.assert_allclose(controller.gain, gain, rtol=1e-8, atol=1e-10)


def test_gains_that_destabilise_the_linearised_rig_are_refused_before_running():
    with pytest.raises(ParameterError, match="destabilise the linearised rig"):
        LQR(DEFAULT_PARAMS, gain=[[0.0, 0.0, -0.05, 0.0], [0.0, 0.0, 0.0, 0.0]])  # negative damping on M1
    stable = LQR(DEFAULT_PARAMS, gain=[[0.0, 0.0, 0.02, 0.0], [0.0, 0.0, 0.0, 0.02]])  # added damping
    a_d, b_d = stable.linear.discrete(0.01, stable.channels)
    assert check_stabilising(a_d, b_d, stable.gain) < 1.0
    with pytest.raises(ParameterError, match=r"\(1, 4\) matrix"):
        LQR(DEFAULT_PARAMS, motors=("m1",), gain=[[0.0, 0.0, 0.02, 0.0], [0.0, 0.0, 0.0, 0.02]])


@pytest.fixture(scope="module")
def open_loop_decay_s() -> np.ndarray:
    """Each mode's open-loop decay time to 1/e from the 30 deg release, from a free MuJoCo run."""
    free = simulate(DEFAULT_PARAMS, RELEASE_30, (0.0, 0.0), 240.0, 0.01)
    amplitudes = linearise(DEFAULT_PARAMS).mode_amplitudes_rad(np.hstack([free.phi_rad, free.omega_rad_s]))
    decay = np.array([decay_time_s(free.t_s, amplitudes[:, i]) for i in range(2)])
    # independent check of the measurement: the linear model's decay time 1/(b/2J) (both modes here)
    expected = 2.0 * DEFAULT_PARAMS.j1_kg_m2 / DEFAULT_PARAMS.b1_n_m_s
    np.testing.assert_allclose(decay, expected, rtol=0.05)
    return decay


def test_lqr_damps_both_modes_ten_times_faster_within_the_torque_limit_on_both_engines(open_loop_decay_s):
    decays = {}
    for engine in ("fast", "mujoco"):
        loop = closed_loop(LQR(DEFAULT_PARAMS), engine=engine, phi0_rad=RELEASE_30, duration_s=12.0)
        m = loop.metrics()
        assert np.all(m.peak_torque_n_m <= 0.05 + 1e-15)
        assert np.all(open_loop_decay_s / m.decay_s >= 10.0), (engine, m.decay_s)
        decays[engine] = m.decay_s
        # the loop's states are what its inputs give when replayed open loop on the engine
        traj = loop.trajectory()
        assert np.max(np.abs(traj.phi_rad - loop.states[:, :2])) < 1e-10
    np.testing.assert_allclose(decays["fast"], decays["mujoco"], rtol=0.10)


def test_lqr_through_noisy_lossy_late_nodes_still_damps_both_modes_ten_times_faster(open_loop_decay_s):
    nodes = Bno055(imperfections=Imperfections(packet_loss=0.05, loss_burst_samples=3.0, latency_s=0.005))
    loop = closed_loop(LQR(DEFAULT_PARAMS), phi0_rad=RELEASE_30, duration_s=12.0, observer=NodeObserver(nodes, seed=4))
    m = loop.metrics()
    assert np.all(open_loop_decay_s / m.decay_s >= 10.0), m.decay_s
    assert np.all(loop.age_s[100:] < 0.2)
    assert not np.array_equal(loop.observed, loop.states[:-1])  # it did see the nodes, not the state


def test_one_motor_on_m1_alone_damps_mode_1_but_hardly_mode_2(open_loop_decay_s):
    """M1 moves little in mode 2 (its shape's M1 component is about 0.09 of M2's), so a motor on
    M1 alone has little authority over mode 2."""
    shapes = linearise(DEFAULT_PARAMS).modes.shapes
    assert abs(shapes[0, 1]) < 0.15 * abs(shapes[1, 1])
    m = closed_loop(LQR(DEFAULT_PARAMS, motors=("m1",)), phi0_rad=RELEASE_30, duration_s=30.0).metrics()
    speedup = open_loop_decay_s / m.decay_s
    assert speedup[0] >= 10.0
    assert 1.0 < speedup[1] < 10.0
    assert m.peak_torque_n_m[1] == 0.0


def test_the_beating_suppressor_keeps_m2_below_a_tenth_of_m1_where_the_open_loop_does_not():
    suppressed = closed_loop(BeatingSuppressor(DEFAULT_PARAMS), phi0_rad=RELEASE_30, duration_s=30.0).metrics()
    free = closed_loop(OpenLoop(DEFAULT_PARAMS), phi0_rad=RELEASE_30, duration_s=30.0).metrics()
    assert free.largest_ratio_m2_m1 > 0.15  # the release mixes the modes: M2 is pulled along
    assert suppressed.largest_ratio_m2_m1 < 0.1
    assert np.all(suppressed.peak_torque_n_m <= 0.05)


def test_the_energy_regulator_holds_mode_1_at_its_target_amplitude():
    target = math.radians(15.0)
    loop = closed_loop(
        EnergyRegulator(DEFAULT_PARAMS, target_amplitudes_rad=(target, 0.0)), phi0_rad=RELEASE_30, duration_s=40.0
    )
    amplitudes = linearise(DEFAULT_PARAMS).mode_amplitudes_rad(loop.states[-500:])
    assert abs(np.mean(amplitudes[:, 0]) - target) < math.radians(0.5)
    assert np.mean(amplitudes[:, 1]) < math.radians(2.0)


def test_the_scheduled_lqr_equals_the_lqr_near_rest_and_stabilises_every_design_amplitude():
    scheduled = ScheduledLQR(DEFAULT_PARAMS)
    plain = LQR(DEFAULT_PARAMS)
    np.testing.assert_allclose(scheduled.gains[0], plain.gain, rtol=1e-12)
    x = np.array([1e-4, -1e-4, 0.0, 1e-4])
    np.testing.assert_allclose(scheduled(x), plain(x), rtol=1e-4)
    assert not np.allclose(scheduled.gains[-1], scheduled.gains[0])  # the large-amplitude design differs


def _watch(observer: NodeObserver, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """What the observer shows of a rig at rest (the noise) at each 10 ms instant: (states, ages)."""
    x = np.array([0.3, -0.2, 0.0, 0.0])
    observer.reset(x)
    shown = [observer.observe(k * 0.01, x, x) for k in range(1, round(seconds / 0.01) + 1)]
    return np.array([o.state for o in shown]), np.array([o.age_s for o in shown])


def test_the_node_observer_loses_the_configured_share_of_samples_and_has_the_gyros_noise():
    config = Bno055(imperfections=Imperfections(packet_loss=0.2, loss_burst_samples=2.0))
    states, _ = _watch(NodeObserver(config, seed=7), 60.0)
    # without latency a sample shows at the first 10 ms instant after it is taken (periods 12.5 ms):
    # each arrived sample changes the rate seen once
    arrived = (np.count_nonzero(np.diff(states[:, 2])) + 1) / (60.0 * 80.0)
    assert arrived == pytest.approx(0.8, abs=0.03)
    sigma = float(np.std(np.unique(states[:, 2])))
    assert sigma == pytest.approx(config.noise_model.gyro_sigma_rad_s[2], rel=0.1)


def test_the_node_observers_latency_ages_what_the_controller_sees():
    prompt = Bno055()
    _, ages_prompt = _watch(NodeObserver(prompt, seed=1), 20.0)
    late = Bno055(imperfections=Imperfections(latency_s=0.02))
    _, ages_late = _watch(NodeObserver(late, seed=1), 20.0)
    assert np.max(ages_prompt[1:]) < 0.0125  # the newest sample is at most one period old
    # exponential latency of mean 20 ms: median 14 ms (less where a newer sample overtakes an older one)
    assert 0.01 < np.median(ages_late[100:]) - np.median(ages_prompt[100:]) < 0.03
