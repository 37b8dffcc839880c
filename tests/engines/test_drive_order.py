"""Driven runs converge at the order of their integrator: the drive evaluated at the RK4 stage
times (``drives.Sampling.STAGES``: the planar reference and the fast engine) is fourth order, the
step's midpoint value held over the step (``Sampling.HELD``: MuJoCo's ``ctrl``) second order.

The truth is ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-12, atol 1e-13) on the planar
equations of motion with the drive evaluated at every instant it asks for (an independent
integrator of the closed-form right-hand side); the order is measured from step halving: the
error at the end of a 20 s run from 30 deg shrinks 16x per halving at fourth order, 4x at second.
"""

import functools
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pendsim_mj.engines import fast_planar, reference
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.rig.drives import (
    NSTAGE,
    Drive,
    Sampling,
    Sine,
    held_inputs,
    signal_values,
    stage_inputs,
    stage_inputs_at_samples,
    stages_of_held,
)
from pendsim_mj.rig.params import DEFAULT_PARAMS

DEG = math.pi / 180
PHI0 = (30 * DEG, 0.0)
DURATION_S = 20.0
STEPS_S = (0.01, 0.005, 0.0025)
DRIVES = {
    "parametric": Drive(pivot_z=Sine(3.0, 1.755)),  # vertical shaking inside mode 1's principal tongue
    "torque": Drive(torque_m1=Sine(0.05, 0.8)),  # a motor torque on M1 below mode 1's frequency
}
ENGINES = {"reference": reference.solve, "fast": fast_planar.solve}


def _exact_end(drive: Drive) -> np.ndarray:
    """(phi1, phi2) at DURATION_S by solve_ivp with the drive at every instant, rad."""
    coef = fast_planar.coefficients([DEFAULT_PARAMS])

    def rhs(t: float, y: np.ndarray) -> list[float]:
        u = np.zeros((4, 1))
        for target in drive.targets:
            u[target.index, 0] = float(signal_values(drive.signal(target), t))
        a1, a2 = fast_planar.accelerations(y[0:1], y[1:2], y[2:3], y[3:4], coef, u)
        return [y[2], y[3], float(a1[0]), float(a2[0])]

    sol = solve_ivp(rhs, (0.0, DURATION_S), [*PHI0, 0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-13)
    assert sol.success
    return np.asarray(sol.y[:2, -1])


@pytest.fixture(scope="module")
def exact() -> dict[str, np.ndarray]:
    return {name: _exact_end(drive) for name, drive in DRIVES.items()}


@functools.cache
def _driven(engine: str, case: str, dt_s: float):
    """One driven run of a planar engine (deterministic), solved once for the tests that compare it:
    the 10 ms runs serve both the convergence test and the agreement test."""
    return ENGINES[engine](DEFAULT_PARAMS, PHI0, (0.0, 0.0), DURATION_S, dt_s, drive=DRIVES[case])


def _ratios(errors: list[float]) -> list[float]:
    return [errors[i] / errors[i + 1] for i in range(len(errors) - 1)]


@pytest.mark.parametrize("engine", list(ENGINES))
@pytest.mark.parametrize("case", list(DRIVES))
def test_driven_runs_converge_at_fourth_order_with_the_drive_at_the_stage_times(engine, case, exact):
    # measured (2-core container): parametric 4.3e-6, 2.7e-7, 1.7e-8 rad (ratios 15.95, 15.99);
    # torque 2.5e-6, 1.6e-7, 1.0e-8 rad (ratios 15.2, 15.6); the ratios tend to 16 as dt shrinks
    errors = [float(np.max(np.abs(_driven(engine, case, dt).phi_rad[-1] - exact[case]))) for dt in STEPS_S]
    first, second = _ratios(errors)
    assert 13.0 < first < 17.5 and 14.5 < second < 17.5, errors
    assert errors[0] < 1e-5  # 10 ms: under 6e-4 deg after 20 s (held: 1.5e-3 rad)


@pytest.mark.parametrize("case", list(DRIVES))
def test_the_held_rule_is_second_order_in_the_planar_engines_and_in_mujoco(case, exact):
    # MuJoCo's rollout holds ctrl over the step (all four RK4 stages see the midpoint value): the
    # midpoint rule, second order. The planar engines reproduce it on request (Sampling.HELD).
    errors = {"fast": [], "mujoco": []}
    for dt in STEPS_S:
        held = fast_planar.solve(DEFAULT_PARAMS, PHI0, (0.0, 0.0), DURATION_S, dt, drive=DRIVES[case],
                                 sampling=Sampling.HELD)  # fmt: skip
        mj = simulate(DEFAULT_PARAMS, PHI0, (0.0, 0.0), DURATION_S, dt, drive=DRIVES[case])
        errors["fast"].append(float(np.max(np.abs(held.phi_rad[-1] - exact[case]))))
        errors["mujoco"].append(float(np.max(np.abs(mj.phi_rad[-1] - exact[case]))))
        assert np.max(np.abs(mj.phi_rad - held.phi_rad)) < 1e-9  # the same scheme: 1e-9 rad
    for name, errs in errors.items():
        assert all(3.6 < r < 4.4 for r in _ratios(errs)), (name, errs)


def test_one_rk4_step_with_stage_inputs_equals_the_reference_to_1e_12_rad():
    rng = np.random.default_rng(11)
    n = 1000
    phi0, omega0 = rng.uniform(-math.pi, math.pi, (n, 2)), rng.uniform(-6.0, 6.0, (n, 2))
    scale = np.array([0.05, 0.05, 8.0, 8.0])  # N m, N m, m/s^2, m/s^2
    inputs = rng.uniform(-1, 1, (n, 1, NSTAGE, 4)) * scale  # start, midpoint, end all different
    plist = [DEFAULT_PARAMS] * n
    ref = reference.integrate(plist, phi0, omega0, 1, 0.01, inputs)
    fast = fast_planar.integrate(fast_planar.coefficients(plist), phi0, omega0, 1, 0.01, inputs=inputs)
    assert np.max(np.abs(fast[1, :2] - ref[1, :2])) < 1e-12
    assert np.max(np.abs(fast[1, 2:] - ref[1, 2:])) < 1e-11
    # each stage's input matters: the start's alone moves the step
    bumped = inputs.copy()
    bumped[:, 0, 0, 0] += 0.01
    moved = fast_planar.integrate(fast_planar.coefficients(plist), phi0, omega0, 1, 0.01, inputs=bumped)
    assert np.all(moved[1, 2] != fast[1, 2])


@pytest.mark.parametrize("case", list(DRIVES))
def test_driven_runs_of_the_reference_and_the_fast_engine_agree_to_1e_12_rad(case):
    # measured: 5.5e-14 rad (parametric), 1.9e-14 rad (torque) over 20 s at 10 ms
    ref, fast = _driven("reference", case, 0.01), _driven("fast", case, 0.01)
    assert np.max(np.abs(fast.phi_rad - ref.phi_rad)) < 1e-12
    np.testing.assert_array_equal(fast.drive_input, ref.drive_input)


def test_stage_inputs_are_the_signal_at_the_start_midpoint_and_end_of_each_step():
    drive = Drive(torque_m1=Sine(0.2, 1.3, 0.4), pivot_z=Sine(2.0, 0.7))
    stages = stage_inputs(drive, 50, 0.02, t0_s=0.3)  # (50, 3, 4)
    t = 0.3 + np.arange(50)[:, None] * 0.02 + np.array([0.0, 0.01, 0.02])
    np.testing.assert_allclose(stages[..., 0], 0.2 * np.sin(2 * np.pi * 1.3 * t + 0.4), rtol=0, atol=1e-15)
    np.testing.assert_allclose(stages[..., 3], 2.0 * np.sin(2 * np.pi * 0.7 * t), rtol=0, atol=1e-14)
    np.testing.assert_array_equal(stages[:, 1], held_inputs(drive, 50, 0.02, t0_s=0.3))  # midpoints: bit for bit
    np.testing.assert_array_equal(stages[1:, 0], stages[:-1, 2])  # a step's end is the next one's start
    samples = stage_inputs_at_samples(stages)
    np.testing.assert_array_equal(samples[:-1], stages[:, 0])
    np.testing.assert_array_equal(samples[-1], stages[-1, 2])
    held = held_inputs(drive, 50, 0.02)
    np.testing.assert_array_equal(stages_of_held(held)[:, 2], held)


def test_held_inputs_give_the_kernel_bit_for_bit_what_they_gave_before_stage_inputs():
    # a (nbatch, nstep, 4) array is held over each step: the same as its stages repeated
    drive = Drive(torque_m2=Sine(0.03, 1.1), support_x=Sine(0.4, 0.9))
    held = held_inputs(drive, 300, 0.01)[None]
    coef = fast_planar.coefficients([DEFAULT_PARAMS])
    phi0, omega0 = np.array([[0.4, -0.2]]), np.array([[0.0, 0.3]])
    as_held = fast_planar.integrate(coef, phi0, omega0, 300, 0.01, inputs=held)
    as_stages = fast_planar.integrate(coef, phi0, omega0, 300, 0.01, inputs=stages_of_held(held))
    np.testing.assert_array_equal(as_held, as_stages)
    ref = reference.integrate([DEFAULT_PARAMS], phi0, omega0, 300, 0.01, held)
    np.testing.assert_array_equal(ref, reference.integrate([DEFAULT_PARAMS], phi0, omega0, 300, 0.01,
                                                           stages_of_held(held)))  # fmt: skip
