"""Physics checks, each against something independent of the MuJoCo model: the planar
Newtonian reference solver, a conservation law, the linearised normal modes, or RK4's order."""

import math

import numpy as np
import pytest

from pendsim_mj.engines import fast_planar, reference
from pendsim_mj.engines.simulation import simulate, simulate_batch
from pendsim_mj.estimation.analysis import log_decrement_damping, zero_crossing_hz
from pendsim_mj.rig.model import Clamp
from pendsim_mj.rig.params import DEFAULT_PARAMS

UNDAMPED = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0)
DEG = math.pi / 180


def test_rest_is_an_equilibrium_with_zero_net_moment():
    k = reference._coefficients([DEFAULT_PARAMS])
    m1, m2, _ = reference.spring_moments(np.zeros(1), np.zeros(1), k)
    # By symmetry of points 2/3 and 6/7 about the rod, the spring moments vanish at rest.
    assert abs(m1[0]) < 1e-15 and abs(m2[0]) < 1e-15
    tr = simulate(DEFAULT_PARAMS, (0.0, 0.0), (0.0, 0.0), 120.0)
    np.testing.assert_array_equal(tr.spring_moment_n_m[0], [0.0, 0.0])
    assert np.max(np.abs(tr.phi_rad)) < 1e-12
    assert np.max(np.abs(tr.omega_rad_s)) < 1e-12


INITIAL_CONDITIONS_DEG = [(30, 0), (0, 30), (-45, 20), (60, -60), (80, 0), (80, 80), (0, -80)]


@pytest.fixture(scope="module")
def damped_runs():
    """The paper's (damped) rig from every initial condition above over 120 s, on MuJoCo and on the
    planar reference, run once: the agreement test and the energy balance below both use them
    (each member of a batch is computed on its own, so a member is the run it would be alone)."""
    phi0 = np.array(INITIAL_CONDITIONS_DEG, dtype=float) * DEG
    return {
        "mujoco": simulate_batch(DEFAULT_PARAMS, phi0, (0.0, 0.0), 120.0),
        "reference": reference.solve_batch(DEFAULT_PARAMS, phi0, (0.0, 0.0), 120.0),
    }


@pytest.mark.parametrize("params", [DEFAULT_PARAMS, UNDAMPED], ids=["damped", "undamped"])
def test_mujoco_agrees_with_the_planar_reference_to_1e_9_rad_over_120_s(params, request):
    phi0 = np.array(INITIAL_CONDITIONS_DEG, dtype=float) * DEG
    if params is DEFAULT_PARAMS:
        runs = request.getfixturevalue("damped_runs")
        mj, ref = runs["mujoco"], runs["reference"]
    else:
        mj = simulate_batch(params, phi0, (0.0, 0.0), 120.0)
        ref = reference.solve_batch(params, phi0, (0.0, 0.0), 120.0)
    worst = np.max(np.abs(mj.phi_rad - ref.phi_rad), axis=(1, 2))
    assert np.all(worst < 1e-9), dict(zip(map(str, INITIAL_CONDITIONS_DEG), worst, strict=True))
    # the derived quantities agree too: forces, moments, IMU readings, energies
    np.testing.assert_allclose(mj.spring_moment_n_m, ref.spring_moment_n_m, atol=1e-9)
    np.testing.assert_allclose(mj.imu_accel_m_s2, ref.imu_accel_m_s2, atol=1e-8)
    np.testing.assert_allclose(mj.imu_angacc_rad_s2, ref.imu_angacc_rad_s2, atol=1e-8)
    np.testing.assert_allclose(mj.potential_j, ref.potential_j, atol=1e-10)
    np.testing.assert_allclose(mj.kinetic_j, ref.kinetic_j, atol=1e-10)
    quat_err = np.minimum(np.abs(mj.imu_quat_wxyz - ref.imu_quat_wxyz), np.abs(mj.imu_quat_wxyz + ref.imu_quat_wxyz))
    assert quat_err.max() < 1e-9


def _relative_energy_drift(dt_s: float, phi0_deg) -> np.ndarray:
    tr = simulate_batch(UNDAMPED, np.array(phi0_deg) * DEG, (0.0, 0.0), 120.0, dt_s)
    e = tr.total_energy_j
    return np.max(np.abs(e - e[:, :1]), axis=1) / e[:, 0]


def test_energy_is_conserved_without_damping_and_the_drift_is_fifth_order_in_dt():
    # Releases of the paper's kind: M1 from 30 deg (the paper) and 80 deg, M2 at rest.
    releases = [(30, 0), (80, 0)]
    coarse = _relative_energy_drift(0.01, releases)
    fine = _relative_energy_drift(0.005, releases)
    assert np.all(coarse < 1e-5), coarse
    # RK4's energy error per step is O(dt^6) for oscillations, so O(dt^5) over a fixed time: 32x.
    assert np.all((fine * 28 < coarse) & (coarse < fine * 36)), coarse / fine


BALANCED_DEG = [(30, 0), (80, 0), (-45, 20)]  # M1 released as in the paper, a large swing, both moving


@pytest.mark.parametrize("engine", ["mujoco", "reference", "fast"])
def test_dissipated_energy_accounts_for_the_energy_lost(engine, request):
    if engine == "fast":
        phi0 = np.array(BALANCED_DEG, dtype=float) * DEG
        tr = fast_planar.solve_batch(DEFAULT_PARAMS, phi0, (0.0, 0.0), 120.0)
        total, dissipated = tr.total_energy_j, tr.dissipated_j
    else:  # these runs are members of the damped runs above: taken from there
        tr = request.getfixturevalue("damped_runs")[engine]
        rows = [INITIAL_CONDITIONS_DEG.index(c) for c in BALANCED_DEG]
        total, dissipated = tr.total_energy_j[rows], tr.dissipated_j[rows]
    lost = total[:, :1] - total
    assert np.all(lost[:, -1] > 0.5 * total[:, 0])  # most of the energy is gone
    # the balance closes to RK4's own energy error (<= 1e-5 of E0 for these runs, see above)
    residual = np.max(np.abs(lost - dissipated), axis=1)
    assert np.all(residual < 3e-5 * total[:, 0]), residual / total[:, 0]


def _linearised_modes(params):
    """Eigenvalues and mode shapes of the reference's state Jacobian at rest, by central
    differences (independent of MuJoCo)."""
    k = reference._coefficients([params])
    n, eps = 4, 1e-6
    jac = np.zeros((n, n))
    for j in range(n):
        step = np.zeros((5, 1))
        step[j] = eps
        jac[:, j] = (reference.derivative(step, k) - reference.derivative(-step, k))[:4, 0] / (2 * eps)
    eigvals, eigvecs = np.linalg.eig(jac)
    upper = eigvals.imag > 0
    return eigvals[upper], eigvecs[:2, upper]


@pytest.mark.parametrize("params", [UNDAMPED, DEFAULT_PARAMS], ids=["undamped", "damped"])
def test_small_amplitude_frequencies_equal_the_linearised_normal_modes(params):
    eigvals, shapes = _linearised_modes(params)
    assert len(eigvals) == 2
    for lam, shape in zip(eigvals, shapes.T, strict=True):
        predicted_hz = lam.imag / (2 * math.pi)
        # excite the pure mode at 0.05 deg (the damping is mass-proportional, so modes are real)
        mode = np.real(shape / shape[np.argmax(np.abs(shape))])
        tr = simulate(params, 1e-3 * mode, (0.0, 0.0), 60.0)
        for k in range(2):
            measured = zero_crossing_hz(tr.t_s, tr.phi_rad[:, k])
            assert measured == pytest.approx(predicted_hz, rel=1e-3), (predicted_hz, measured)


def test_rk4_error_shrinks_16_fold_per_halving_of_dt():
    # largest error over 10 s against the reference at a step 1/8 of the finest one
    fine_dt = 0.000625
    phi0 = np.array([[60 * DEG, -20 * DEG]])
    exact = reference.solve_batch(DEFAULT_PARAMS, phi0, (0.0, 0.0), 10.0, fine_dt).phi_rad[0]
    errors = []
    for dt in (0.02, 0.01, 0.005):
        tr = simulate(DEFAULT_PARAMS, phi0[0], (0.0, 0.0), 10.0, dt)
        errors.append(np.max(np.abs(tr.phi_rad - exact[:: round(dt / fine_dt)])))
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(13 < r < 19 for r in ratios), (errors, ratios)


@pytest.mark.parametrize(("excited", "clamp"), [(0, Clamp.M2), (1, Clamp.M1)])
def test_log_decrement_of_a_free_decay_recovers_the_damping(excited, clamp):
    # paper: b = 2 J ln(A0 / AT) / t1 over t1 = 120 s, one pendulum swinging, the other clamped
    params = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0011, b2_n_m_s=0.0004)
    phi0 = [0.0, 0.0]
    phi0[excited] = 20 * DEG
    tr = simulate(params, phi0, (0.0, 0.0), 125.0, clamp=clamp)
    assert np.all(tr.phi_rad[:, 1 - excited] == 0.0)
    inertia = (params.j1_kg_m2, params.j2_kg_m2)[excited]
    b_set = (params.b1_n_m_s, params.b2_n_m_s)[excited]
    b, a0, at, t1 = log_decrement_damping(tr.t_s, tr.phi_rad[:, excited], inertia, 120.0)
    assert 119 < t1 <= 120.0 and at < a0
    assert b == pytest.approx(b_set, rel=0.02)
