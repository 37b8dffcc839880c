"""The compiled held-torque RK4 step of a batch of sigma points (``twin.unscented.advanced``, what
the twin's prediction takes) against the numpy step of the control plant and against the
independent reference solver."""

from __future__ import annotations

import numpy as np

from pendsim_mj.control.plant import FastPlant
from pendsim_mj.engines import reference
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.twin.unscented import advanced

NO_ROWS = np.zeros(0, dtype=np.intp)
NO_CHAIN = (NO_ROWS, np.zeros(0), np.zeros(0), NO_ROWS)


def test_one_held_step_of_members_with_their_own_constants_equals_the_numpy_step():
    rng = np.random.default_rng(7)
    n = 23
    plant = FastPlant(DEFAULT_PARAMS.with_overrides(friction1_n_m=2e-4, friction2_n_m=1e-4), nenv=n, dt_s=0.0047)
    plant.coef[:] *= 1 + 1e-3 * rng.normal(size=plant.coef.shape)  # each member its own rig
    points = np.hstack([rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(-3, 3, (n, 2))])  # (n, 4): phi, omega
    tau = rng.normal(0, 0.02, 2)
    out = advanced(points, plant.coef, NO_ROWS, tau, plant.dt_s, NO_ROWS, NO_CHAIN)
    back = advanced(out, plant.coef, NO_ROWS, tau, -plant.dt_s, NO_ROWS, NO_CHAIN)
    assert np.max(np.abs(back - points)) < 1e-8  # a step back returns to within RK4's error
    plant.columns[:] = points.T
    plant.advance(np.vstack([np.repeat(tau[:, None], n, axis=1), np.zeros((2, n))]))
    assert np.max(np.abs(out.T - plant.columns)) < 1e-13
    assert np.max(np.abs(out - points)) > 1e-3  # it moved


def test_a_tracked_parameter_sets_its_points_own_constant():
    """A sigma point's tracked damping (its column 4, the force law's b1 row) is the one its step
    uses: two points equal but for b1 move apart as the damping torque -b1 omega1 says."""
    from pendsim_mj.engines.fast_planar.closed_form import COEFFICIENTS

    plant = FastPlant(DEFAULT_PARAMS, nenv=2, dt_s=0.01)
    rows = np.array([COEFFICIENTS.index("b1_n_m_s")], dtype=np.intp)
    points = np.array([[0.0, 0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0, 0.01]])
    out = advanced(points, plant.coef, rows, np.zeros(2), 0.01, NO_ROWS, NO_CHAIN)
    # at the bottom with omega1 = 2 rad/s, 0.01 N m s/rad more damping slows omega1 by about
    # 0.01 * 2 / J1 * 0.01 s
    slowed = (out[0, 2] - out[1, 2]) / (0.01 * 2.0 * 0.01 / DEFAULT_PARAMS.j1_kg_m2)
    assert 0.95 < slowed < 1.05
    assert np.array_equal(out[:, 4], points[:, 4])  # the parameter rides along


def test_steps_of_the_held_kernel_follow_the_reference_solver():
    phi0, dt, steps = (0.6, -0.2), 0.01, 300
    truth = reference.solve(DEFAULT_PARAMS, phi0, (0.0, 0.0), steps * dt, dt)
    plant = FastPlant(DEFAULT_PARAMS, nenv=1, dt_s=dt)
    x = np.array([[phi0[0], phi0[1], 0.0, 0.0]])
    for _ in range(steps):
        x = advanced(x, plant.coef, NO_ROWS, np.zeros(2), dt, NO_ROWS, NO_CHAIN)
    np.testing.assert_allclose(x[0, :2], truth.phi_rad[-1], atol=1e-9)
    np.testing.assert_allclose(x[0, 2:], truth.omega_rad_s[-1], atol=1e-9)


def test_a_point_that_moves_as_the_first_takes_its_step_and_every_other_its_own():
    """Sigma points along a tracked parameter that does not enter the force law (an offset) have
    the first point's state and constants: they take its step (bit for bit the same numbers), while
    a point with its own damping or its own state is stepped on its own: each equals the point
    stepped alone."""
    from pendsim_mj.engines.fast_planar.closed_form import COEFFICIENTS

    rows = np.array([COEFFICIENTS.index("b1_n_m_s"), -1], dtype=np.intp)  # tracked: b1, then an offset
    first = np.array([0.3, -0.2, 1.0, 0.5, DEFAULT_PARAMS.b1_n_m_s, 0.0])
    moves = np.array([[0, 0, 0, 0, 0, 0.0], [0, 0, 0, 0, 0, 0.01], [0, 0, 0, 0, 1e-3, 0], [1e-3, 0, 0, 0, 0, 0]])
    points = first + moves  # the first; its offset moved; its damping moved; its angle moved
    tau = np.array([0.004, -0.002])
    out = advanced(points, FastPlant(DEFAULT_PARAMS, nenv=4).coef, rows, tau, 0.01, NO_ROWS, NO_CHAIN)
    for i, point in enumerate(points):
        one = FastPlant(DEFAULT_PARAMS, nenv=1).coef
        alone = advanced(point[None, :].copy(), one, rows, tau, 0.01, NO_ROWS, NO_CHAIN)
        assert np.array_equal(out[i], alone[0])
    assert np.array_equal(out[1, :4], out[0, :4]) and out[1, 5] == 0.01
    assert np.all(out[2, 2:4] != out[0, 2:4]) and out[3, 0] != out[0, 0]
