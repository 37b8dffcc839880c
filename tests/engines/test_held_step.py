"""The compiled held-input RK4 step of a batch (what the twin's sigma points take) against the
numpy step of the control plant and against the independent reference solver."""

from __future__ import annotations

import numpy as np

from pendsim_mj.control.plant import FastPlant
from pendsim_mj.engines import reference
from pendsim_mj.engines.fast_planar.step import rk4_held
from pendsim_mj.rig.params import DEFAULT_PARAMS


def test_one_held_step_of_members_with_their_own_constants_equals_the_numpy_step():
    rng = np.random.default_rng(7)
    n = 23
    plant = FastPlant(DEFAULT_PARAMS.with_overrides(friction1_n_m=2e-4, friction2_n_m=1e-4), nenv=n, dt_s=0.0047)
    plant.coef[:] *= 1 + 1e-3 * rng.normal(size=plant.coef.shape)  # each member its own rig
    x = np.vstack([rng.uniform(-1.5, 1.5, (2, n)), rng.uniform(-3, 3, (2, n))])
    u = np.vstack([rng.normal(0, 0.02, (2, n)), rng.normal(0, 0.5, (2, n))])  # torques and support motion
    out = np.empty_like(x)
    rk4_held(plant.coef, x, u, plant.dt_s, out)
    back = np.empty_like(x)
    rk4_held(plant.coef, out, u, -plant.dt_s, back)  # a step back returns to within RK4's error
    assert np.max(np.abs(back - x)) < 1e-8
    plant.columns[:] = x
    plant.advance(u)
    assert np.max(np.abs(out - plant.columns)) < 1e-13
    assert np.max(np.abs(out - x)) > 1e-3  # it moved


def test_steps_of_the_held_kernel_follow_the_reference_solver():
    phi0, dt, steps = (0.6, -0.2), 0.01, 300
    truth = reference.solve(DEFAULT_PARAMS, phi0, (0.0, 0.0), steps * dt, dt)
    plant = FastPlant(DEFAULT_PARAMS, nenv=1, dt_s=dt)
    x = np.array([[phi0[0]], [phi0[1]], [0.0], [0.0]])
    u = np.zeros((4, 1))
    for _ in range(steps):
        out = np.empty_like(x)
        rk4_held(plant.coef, x, u, dt, out)
        x = out
    np.testing.assert_allclose(x[:2, 0], truth.phi_rad[-1], atol=1e-9)
    np.testing.assert_allclose(x[2:, 0], truth.omega_rad_s[-1], atol=1e-9)
