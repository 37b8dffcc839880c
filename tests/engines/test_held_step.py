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
