"""Dry (Coulomb) friction at the hinges: MuJoCo's joint frictionloss against the planar
reference's explicit law, and both against the analytic friction-damped oscillator."""

import math

import numpy as np
import pytest

from pendsim_mj.engines import fast_planar, reference
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.rig.params import DEFAULT_PARAMS

DRY = DEFAULT_PARAMS.with_overrides(friction1_n_m=5e-4, friction2_n_m=5e-4)


def test_mujoco_frictionloss_and_the_reference_law_agree_on_the_coupled_rig():
    # measured: 0.55 mrad over 5 s from 30 deg, energies within 0.05 % after 30 s (docs/identification.md)
    phi0 = (math.radians(30), 0.0)
    mj = simulate(DRY, phi0, (0.0, 0.0), 30.0)
    ref = reference.solve(DRY, phi0, (0.0, 0.0), 30.0)
    delta = np.abs(mj.phi_rad - ref.phi_rad)
    assert delta[:501].max() < 1.5e-3  # rad, 5 s
    assert delta.max() < 6e-3  # rad, 30 s
    e_mj, e_ref = mj.total_energy_j[-1], ref.total_energy_j[-1]
    frictionless = simulate(DEFAULT_PARAMS, phi0, (0.0, 0.0), 30.0).total_energy_j[-1]
    assert e_ref < 0.9 * frictionless  # the friction takes a real share of the energy
    assert e_ref == pytest.approx(e_mj, rel=0.005)


def test_fast_kernel_with_friction_equals_the_reference():
    fast = fast_planar.solve(DRY, (0.5, -0.2), (0.3, 0.0), 10.0)
    ref = reference.solve(DRY, (0.5, -0.2), (0.3, 0.0), 10.0)
    assert np.max(np.abs(fast.phi_rad - ref.phi_rad)) < 1e-12


def _peaks(t, x):
    i = np.flatnonzero((x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:])) + 1
    return t[i], x[i]


@pytest.mark.parametrize("engine", ["reference", "mujoco"])
def test_a_dry_friction_oscillator_loses_4F_over_k_of_amplitude_per_period(engine):
    # one pendulum, no springs, no viscous damping, small angles: phi'' = -(k/J) phi - (F/J) sign(phi'),
    # whose amplitude falls linearly by 4 F / k per period (k = m1 g OC1)
    friction = 2e-4
    p = DEFAULT_PARAMS.with_overrides(c1_n_m=0.0, c2_n_m=0.0, b1_n_m_s=0.0, b2_n_m_s=0.0, friction1_n_m=friction)
    phi0 = (0.03, 0.0)
    run = (reference.solve if engine == "reference" else simulate)(p, phi0, (0.0, 0.0), 12.0)
    _, amplitude = _peaks(run.t_s, run.phi_rad[:, 0])
    k = p.m1_kg * p.g_m_s2 * p.oc1_m
    drop = np.diff(amplitude[:8])
    np.testing.assert_allclose(drop, -4 * friction / k, rtol=0.03)
    assert np.all(np.abs(np.diff(drop)) < 0.03 * 4 * friction / k)  # linear, not exponential


def test_mujoco_holds_a_stopped_pendulum_off_centre_where_the_smoothed_law_creeps_to_the_bottom():
    # Coulomb friction holds a pendulum at rest wherever the static moment on it (gravity and the
    # springs, the reference's force law at zero rate) is within F. MuJoCo's frictionloss, a soft
    # constraint, holds it off-centre and lets it creep down over tens of seconds (0.40 deg at
    # 15 s, 0.09 at 60 s); the planar engines' smoothed law creeps there in seconds (what
    # `simulate` says with dry friction). The static moments come from the reference, an
    # independent model of the rig.
    friction = 0.01  # N m: both pendulums stop about 10 s after a 30 deg release
    rig = DEFAULT_PARAMS.with_mapping({"friction1_n_m": friction, "friction2_n_m": friction})
    mj = simulate(rig, (math.radians(30), 0.0), (0.0, 0.0), 15.0)
    assert np.abs(mj.omega_rad_s[-1]).max() < 1e-3  # stopped: creeping at most
    k = reference._coefficients([rig])
    at_rest = np.array([*mj.phi_rad[-1], 0.0, 0.0, 0.0]).reshape(5, 1)
    static = reference.derivative(at_rest, k)[2:4, 0] * np.array([k.j1[0], k.j2[0]])  # N m
    assert np.all(np.abs(static) <= 1.05 * friction), static  # within the friction's reach
    assert np.abs(static).max() > 0.2 * friction, static  # and off-centre: held against a real moment
    fast = fast_planar.solve(rig, (math.radians(30), 0.0), (0.0, 0.0), 15.0)
    assert np.abs(fast.phi_rad[-1]).max() < 0.1 * np.abs(mj.phi_rad[-1]).max()  # the smoothed law crept on
