"""The fast planar engine against the paper-chain reference: closed form, one step, whole runs,
energies; its kernel's own properties (sin/cos, batch independence, divergence, Lyapunov)."""

import math

import numba
import numpy as np
import pytest

from pendsim_mj.engines import fast_planar, reference
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.rig.drives import Chirp, Drive, Sine, SteppedSine
from pendsim_mj.rig.params import DEFAULT_PARAMS

UNDAMPED = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0)
# The general geometry: points 2/3 and 6/7 not symmetric, so the cosine terms of the closed form
# are not zero (on the paper's rig they are).
ASYMMETRIC = DEFAULT_PARAMS.with_overrides(l24_m=0.120, l34_m=0.170, l68_m=0.185, l78_m=0.110, c1_n_m=9.0)
FRICTION = DEFAULT_PARAMS.with_overrides(friction1_n_m=2e-3, friction2_n_m=1e-3)  # dry friction at both hinges
DEG = math.pi / 180


def _random_states(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-math.pi, math.pi, (n, 2)), rng.uniform(-6.0, 6.0, (n, 2))


@pytest.mark.parametrize("params", [DEFAULT_PARAMS, ASYMMETRIC], ids=["paper", "asymmetric"])
def test_closed_form_spring_moments_equal_the_paper_chain(params):
    phi, _ = _random_states(2000, 1)
    phi = np.concatenate([phi, [[0.0, 0.0], [math.pi, -math.pi], [1e-9, -1e-9]]])
    k_ref = reference._coefficients([params] * len(phi))
    m1_ref, m2_ref, springs = reference.spring_moments(phi[:, 0], phi[:, 1], k_ref)
    k = fast_planar.coefficients([params] * len(phi))
    m1, m2 = fast_planar.spring_moments(phi[:, 0], phi[:, 1], k)
    np.testing.assert_allclose(m1, m1_ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(m2, m2_ref, rtol=0, atol=1e-15)
    lengths = fast_planar.spring_lengths(phi[:, 0], phi[:, 1], [params] * len(phi))
    np.testing.assert_allclose(lengths, springs.length_m, rtol=0, atol=1e-13)  # m


def test_spring_potential_is_half_c_l_squared_and_its_slopes_are_the_moments():
    phi, _ = _random_states(500, 2)
    n = len(phi)
    k = fast_planar.coefficients([ASYMMETRIC] * n)
    k_ref = reference._coefficients([ASYMMETRIC] * n)
    p = ASYMMETRIC
    c = np.array([p.c1_n_m, p.c1_n_m, p.c2_n_m, p.c2_n_m])[:, None]

    def chain_potential(a1: np.ndarray, a2: np.ndarray) -> np.ndarray:
        """Gravity + 1/2 sum c L^2 from the reference's spring lengths, above phi = 0."""
        _, _, springs = reference.spring_moments(a1, a2, k_ref)
        _, _, rest = reference.spring_moments(np.zeros(n), np.zeros(n), k_ref)
        spring = 0.5 * np.sum(c * (springs.length_m**2 - rest.length_m**2), axis=0)
        return k_ref.gravity1 * (1 - np.cos(a1)) + k_ref.gravity2 * (1 - np.cos(a2)) + spring

    v = fast_planar.potential_energy(phi[:, 0], phi[:, 1], k)
    np.testing.assert_allclose(v, chain_potential(phi[:, 0], phi[:, 1]), rtol=0, atol=1e-14)
    # minus the slope of the spring potential is the moment (central differences, h = 1e-6 rad)
    h = 1e-6
    m1, m2 = fast_planar.spring_moments(phi[:, 0], phi[:, 1], k)
    grav1 = k_ref.gravity1 * np.sin(phi[:, 0])
    grav2 = k_ref.gravity2 * np.sin(phi[:, 1])
    dv1 = (chain_potential(phi[:, 0] + h, phi[:, 1]) - chain_potential(phi[:, 0] - h, phi[:, 1])) / (2 * h)
    dv2 = (chain_potential(phi[:, 0], phi[:, 1] + h) - chain_potential(phi[:, 0], phi[:, 1] - h)) / (2 * h)
    np.testing.assert_allclose(-dv1, m1 - grav1, atol=1e-8)
    np.testing.assert_allclose(-dv2, m2 - grav2, atol=1e-8)


@pytest.mark.parametrize(
    "params", [DEFAULT_PARAMS, ASYMMETRIC, UNDAMPED, FRICTION], ids=["paper", "asymmetric", "undamped", "friction"]
)
def test_one_rk4_step_equals_the_reference_to_1e_12_rad(params):
    phi0, omega0 = _random_states(1000, 3)
    plist = [params] * len(phi0)
    for dt in (0.01, 0.002):
        ref = reference.integrate(plist, phi0, omega0, 1, dt)
        fast = fast_planar.integrate(fast_planar.coefficients(plist), phi0, omega0, 1, dt)
        assert fast.shape == ref.shape == (2, 5, 1000)
        np.testing.assert_array_equal(fast[0], ref[0])
        assert np.max(np.abs(fast[1, :2] - ref[1, :2])) < 1e-12  # rad
        assert np.max(np.abs(fast[1, 2:4] - ref[1, 2:4])) < 1e-11  # rad/s
        assert np.max(np.abs(fast[1, 4] - ref[1, 4])) < 1e-14  # J dissipated


@pytest.mark.parametrize("params", [DEFAULT_PARAMS, ASYMMETRIC, FRICTION], ids=["paper", "asymmetric", "friction"])
def test_whole_runs_equal_the_reference_trajectory(params):
    # the releases of tests/engines/test_physics.py, 30 s at 10 ms
    phi0 = np.array([(30, 0), (0, 30), (-45, 20), (60, -60), (80, 0), (80, 80), (0, -80)], dtype=float) * DEG
    omega0 = np.zeros_like(phi0)
    fast = fast_planar.solve_batch(params, phi0, omega0, 30.0)
    ref = reference.solve_batch(params, phi0, omega0, 30.0)
    assert fast.engine == "fast" and fast.params == ref.params
    np.testing.assert_array_equal(fast.t_s, ref.t_s)
    assert np.max(np.abs(fast.phi_rad - ref.phi_rad)) < 1e-10
    tolerances = {"omega_rad_s": 1e-9, "alpha_rad_s2": 1e-8, "imu_accel_m_s2": 1e-8, "imu_angacc_rad_s2": 1e-8}
    for name in fast.ARRAY_FIELDS:
        np.testing.assert_allclose(getattr(fast, name), getattr(ref, name), rtol=0, atol=tolerances.get(name, 1e-10))


@pytest.mark.parametrize("params", [DEFAULT_PARAMS, ASYMMETRIC], ids=["paper", "asymmetric"])
def test_one_driven_rk4_step_equals_the_reference_to_1e_12_rad(params):
    # torques and support accelerations held over the step, random in sign and size
    phi0, omega0 = _random_states(1000, 6)
    rng = np.random.default_rng(7)
    inputs = rng.uniform(-1, 1, (1000, 1, 4)) * np.array([0.05, 0.05, 8.0, 8.0])  # N m, N m, m/s^2, m/s^2
    plist = [params] * len(phi0)
    ref = reference.integrate(plist, phi0, omega0, 1, 0.01, inputs)
    fast = fast_planar.integrate(fast_planar.coefficients(plist), phi0, omega0, 1, 0.01, inputs=inputs)
    assert np.max(np.abs(fast[1, :2] - ref[1, :2])) < 1e-12
    assert np.max(np.abs(fast[1, 2:] - ref[1, 2:])) < 1e-11


def test_driven_runs_equal_the_reference_trajectory_for_every_drive_and_signal():
    drive = Drive(
        torque_m1=Sine(0.01, 0.9),
        torque_m2=SteppedSine(0.008, (0.7, 1.1), 5.0),
        support_x=Sine(0.5, 1.3, 0.2),
        pivot_z=Chirp(2.0, 0.5, 3.0, 10.0, law="log"),
    )
    phi0 = np.array([(30, 0), (10, -20), (80, 60)], dtype=float) * DEG
    fast = fast_planar.solve_batch(DEFAULT_PARAMS, phi0, (0.0, 0.0), 10.0, drive=drive)
    ref = reference.solve_batch(DEFAULT_PARAMS, phi0, (0.0, 0.0), 10.0, drive=drive)
    assert np.max(np.abs(fast.phi_rad - ref.phi_rad)) < 1e-10 and fast.drive == ref.drive
    np.testing.assert_array_equal(fast.drive_input, ref.drive_input)
    np.testing.assert_array_equal(fast.support_m, ref.support_m)
    for name in ("alpha_rad_s2", "imu_accel_m_s2", "kinetic_j", "potential_j", "dissipated_j"):
        np.testing.assert_allclose(getattr(fast, name), getattr(ref, name), rtol=0, atol=1e-8, err_msg=name)


def test_single_run_is_a_batch_member_with_the_reference_arguments():
    single = fast_planar.solve(DEFAULT_PARAMS, (0.4, -0.2), (0.1, 0.0), 3.0)
    ref = reference.solve(DEFAULT_PARAMS, (0.4, -0.2), (0.1, 0.0), 3.0)
    assert single.phi_rad.shape == ref.phi_rad.shape == (301, 2)
    assert np.max(np.abs(single.phi_rad - ref.phi_rad)) < 1e-12


def test_energy_balance_closes_without_damping_and_with_it():
    phi0 = np.array([(30, 0), (80, 0), (170, -150)], dtype=float) * DEG
    for params in (UNDAMPED, DEFAULT_PARAMS, FRICTION):
        tr = fast_planar.solve_batch(params, phi0, (0.0, 0.0), 60.0)
        e0 = tr.total_energy_j[:, :1]
        residual = np.abs(e0 - tr.total_energy_j - tr.dissipated_j)
        assert np.all(residual.max(axis=1) < 1e-4 * e0[:, 0]), residual.max(axis=1) / e0[:, 0]


def test_sin_and_cos_are_within_one_ulp_of_libm():
    x = np.concatenate([np.linspace(-1e5, 1e5, 400_001), np.linspace(-7, 7, 100_001), np.pi / 2 * np.arange(-40, 41)])

    s, c = _sincos_array(x)
    # 1 ulp of a value of magnitude 1 is 2.2e-16; near the zeros both agree to far better
    assert np.max(np.abs(s - np.sin(x))) <= 2.3e-16
    assert np.max(np.abs(c - np.cos(x))) <= 2.3e-16
    np.testing.assert_array_max_ulp(s[np.abs(s) > 1e-3], np.sin(x)[np.abs(s) > 1e-3], maxulp=2)


@numba.njit
def _sincos_array(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.empty_like(x)
    c = np.empty_like(x)
    for i in range(len(x)):
        s[i], c[i] = fast_planar.sincos(x[i])
    return s, c


def test_a_member_gives_the_same_bits_alone_and_anywhere_in_a_batch():
    phi0, omega0 = _random_states(203, 4)  # 203: full SIMD chunks and a scalar remainder
    k = fast_planar.coefficients([FRICTION] * len(phi0))  # the dry-friction law too
    batch = fast_planar.integrate(k, phi0, omega0, 500, 0.01)
    for i in (0, 7, 64, 130, 202):
        alone = fast_planar.integrate(k[:, i : i + 1], phi0[i : i + 1], omega0[i : i + 1], 500, 0.01)
        np.testing.assert_array_equal(alone[..., 0], batch[..., i])
    one_thread = fast_planar.integrate(k, phi0, omega0, 500, 0.01, nthread=1)
    np.testing.assert_array_equal(one_thread, batch)


def test_saving_every_kth_state_keeps_exactly_those_states():
    phi0, omega0 = _random_states(10, 5)
    k = fast_planar.coefficients([DEFAULT_PARAMS] * 10)
    every = fast_planar.integrate(k, phi0, omega0, 300, 0.01)
    sparse = fast_planar.integrate(k, phi0, omega0, 300, 0.01, save_every=50)
    assert sparse.shape == (7, 5, 10)
    np.testing.assert_array_equal(sparse, every[::50])
    with pytest.raises(ParameterError, match="save_every must be a whole number >= 1 that divides nstep = 300"):
        fast_planar.integrate(k, phi0, omega0, 300, 0.01, save_every=7)
    with pytest.raises(ParameterError, match=r"coef must have shape \(14, 3\)"):
        fast_planar.integrate(k, phi0[:3], omega0[:3], 300, 0.01)


def test_a_diverging_member_is_flagged_by_integrate_and_raises_in_solve():
    stiff = DEFAULT_PARAMS.with_overrides(c1_n_m=1e6)  # RK4 at 10 ms is unstable for this spring
    plist = [DEFAULT_PARAMS, stiff, DEFAULT_PARAMS]
    k = fast_planar.coefficients(plist)
    states = fast_planar.integrate(k, np.full((3, 2), 0.5), np.zeros((3, 2)), 1000, 0.01)
    np.testing.assert_array_equal(fast_planar.diverged(states, k), [False, True, False])
    states[500, 0, 2] = np.nan
    np.testing.assert_array_equal(fast_planar.diverged(states, k), [False, True, True])
    with pytest.raises(SimulationDiverged, match=r"diverged.*reduce dt_s"):
        fast_planar.solve_batch(plist, np.full((3, 2), 0.5), (0.0, 0.0), 10.0)


def test_lyapunov_exponent_at_rest_of_the_damped_rig_is_the_modal_decay_rate():
    # b_n / J_n is the same for both pendulums (both decay to 20 % in 120 s), so the linearised
    # rig has proportional damping and every mode decays at b / (2 J) = ln(5) / 120 per second.
    # Benettin's estimate over T carries an O(1/T) term from the oscillating separation.
    duration_s = 2000.0
    lam = fast_planar.lyapunov(
        fast_planar.coefficients([DEFAULT_PARAMS]), np.zeros((1, 2)), np.zeros((1, 2)), 200_000, 0.01
    )
    assert lam.shape == (2000, 1)
    assert lam[-1, 0] == pytest.approx(-math.log(5) / 120, abs=3.0 / duration_s)


def test_lyapunov_exponent_equals_benettin_on_the_reference_solver():
    # the same method written out on two runs of the reference, renormalised here
    phi0 = np.array([[30 * DEG, 0.0]])
    omega0 = np.zeros((1, 2))
    d0, every, rounds = 1e-8, 100, 15
    lam = fast_planar.lyapunov(fast_planar.coefficients([DEFAULT_PARAMS]), phi0, omega0, every * rounds, 0.01)
    base = np.concatenate([phi0[0], omega0[0]])
    shadow = base + 0.5 * d0
    total = 0.0
    for _ in range(rounds):
        pair = np.stack([base, shadow])
        states = reference.integrate([DEFAULT_PARAMS] * 2, pair[:, :2], pair[:, 2:], every, 0.01)[-1, :4]
        base, shadow = states[:, 0], states[:, 1]
        dist = np.linalg.norm(shadow - base)
        total += math.log(dist / d0)
        shadow = base + (shadow - base) * d0 / dist
    expected = total / (rounds * every * 0.01)
    assert lam[-1, 0] == pytest.approx(expected, abs=1e-6)


def test_lyapunov_exponent_is_positive_for_chaos_and_vanishes_for_a_regular_orbit():
    phi0 = np.array([(30, 0), (150, -150)], dtype=float) * DEG  # a 30 deg release; a chaotic orbit
    lam = fast_planar.lyapunov(fast_planar.coefficients([UNDAMPED] * 2), phi0, np.zeros((2, 2)), 100_000, 0.01)
    regular, chaotic = lam[:, 0], lam[:, 1]
    assert abs(regular[-1]) < 0.02 and abs(regular[-1]) < abs(regular[99])  # decays like log(T)/T
    assert chaotic[-1] > 0.3 and chaotic[-1] == pytest.approx(chaotic[499], rel=0.25)  # settled, positive


def test_pendsim_simulate_runs_on_the_fast_engine_and_writes_the_reference_trajectory(tmp_path, capsys):
    from pendsim_bridge.cli import main

    out = tmp_path / "fast.npz"
    assert main(["simulate", "--engine", "fast", "--duration-s", "5", "--phi1-deg", "40", "-o", str(out)]) == 0
    assert "engine fast" in capsys.readouterr().out
    expected = reference.solve(DEFAULT_PARAMS, (40 * DEG, 0.0), (0.0, 0.0), 5.0)
    assert np.max(np.abs(np.load(out)["phi_rad"] - expected.phi_rad)) < 1e-12


def test_pendsim_simulate_gives_no_frequency_for_a_pendulum_that_goes_over_the_top(capsys):
    """Released at 121.9 and 146.6 deg, M1 turns over and over (the reference run's phi1 passes
    pi): the peak of its angle's spectrum, the ramp of its turns, was printed as a swing's 0.0333 Hz."""
    from pendsim_bridge.cli import main

    args = ["simulate", "--engine", "fast", "--duration-s", "30", "--phi1-deg", "121.9159", "--phi2-deg", "146.6202"]
    assert main(args) == 0
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.startswith("phi")}
    assert "n/a (turned over)" in rows["phi1"] and rows["phi1"].split()[-2:] == ["n/a", "n/a"]  # no peaks of turns
    run = reference.solve(DEFAULT_PARAMS, (121.9159 * DEG, 146.6202 * DEG), (0.0, 0.0), 30.0)
    assert np.max(np.abs(run.phi_rad[:, 0])) > np.pi


def test_pendsim_simulate_gives_no_frequency_for_a_pendulum_that_does_not_complete_a_cycle(capsys):
    """M1 on an overdamped hinge (0.5 N m s/rad) creeps back to rest: its spectrum's largest peak is
    the lowest bin (a few micro-hertz), which was printed as 0.0000 Hz; M2, still swinging, keeps its
    frequency (the reference run's own spectral peak)."""
    from pendsim_bridge.cli import main
    from pendsim_mj.estimation.analysis import spectral_peak_hz

    assert main(["simulate", "--engine", "fast", "--duration-s", "20", "--set", "b1_n_m_s=0.5"]) == 0
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.startswith("phi")}
    assert "n/a (< 1 cycle)" in rows["phi1"]
    run = reference.solve(DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.5), (30 * DEG, 0.0), (0.0, 0.0), 20.0)
    assert spectral_peak_hz(run.t_s, run.phi_rad[:, 0]) * 20.0 < 1.0
    assert float(rows["phi2"].split()[1]) == pytest.approx(spectral_peak_hz(run.t_s, run.phi_rad[:, 1]), abs=1e-4)


def test_blocks_continue_one_run_bit_for_bit_and_equal_the_reference_blocks():
    from pendsim_mj.engines import dispatch as engines

    start = ((0.6, -0.2), (0.1, 0.4))
    whole = fast_planar.solve(DEFAULT_PARAMS, *start, duration_s=3.0)
    fast = list(engines.run_blocks("fast", DEFAULT_PARAMS, *start, duration_s=3.0, block_steps=70))
    ref = list(engines.run_blocks("reference", DEFAULT_PARAMS, *start, duration_s=3.0, block_steps=70))
    assert [f for f, _ in fast] == [f for f, _ in ref] == list(range(0, 300, 70))
    for (first, block), (_, ref_block) in zip(fast, ref, strict=True):
        rows = slice(first, first + len(block.t_s))
        assert np.array_equal(block.t_s, whole.t_s[rows])
        for name in ("phi_rad", "omega_rad_s", "imu_accel_m_s2", "spring_force_n", "dissipated_j"):
            assert np.array_equal(getattr(block, name), getattr(whole, name)[rows]), name
        np.testing.assert_allclose(block.phi_rad, ref_block.phi_rad, rtol=0, atol=1e-12)
        np.testing.assert_allclose(block.dissipated_j, ref_block.dissipated_j, rtol=0, atol=1e-12)


def test_rates_at_the_steps_equal_integrate_and_their_sensitivities_equal_central_differences():
    """rates_at: the kernel's states at the step instants; its sensitivities the derivative of the
    same discrete solution (central differences converge to them as step^2)."""
    coef = fast_planar.coefficients([FRICTION])
    t = np.arange(401) * 0.01
    states = fast_planar.integrate(coef, np.array([[0.5, 0.1]]), np.array([[0.2, -0.3]]), 400, 0.01, nthread=1)
    (r1, r2), _, _ = fast_planar.rates_at(coef, (0.5, 0.1), (0.2, -0.3), (t, t), 0.01)
    np.testing.assert_allclose(r1, states[:, 2, 0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(r2, states[:, 3, 0], rtol=0, atol=1e-13)
    at = (np.sort(np.random.default_rng(3).uniform(0, 4, 300)), np.linspace(0.0051, 3.9, 250))
    wrt = fast_planar.SENSITIVITY_NAMES
    _, sens, slope = fast_planar.rates_at(coef, (0.5, 0.1), (0.2, -0.3), at, 0.01, release_s=0.02, wrt=wrt)
    state = {"phi1_0": 0.5, "phi2_0": 0.1, "omega1_0": 0.2, "omega2_0": -0.3, "release": 0.02}
    for col, name in enumerate([*wrt, "release"]):
        step = 1e-7 if name.endswith("_0") or name == "release" else 1e-8
        pair = []
        for sign in (1.0, -1.0):
            k, x = coef.copy(), dict(state)
            if name in x:
                x[name] += sign * step
            else:
                k[fast_planar.COEFFICIENTS.index(name)] += sign * step
            phi0, omega0 = (x["phi1_0"], x["phi2_0"]), (x["omega1_0"], x["omega2_0"])
            pair.append(np.concatenate(fast_planar.rates_at(k, phi0, omega0, at, 0.01, release_s=x["release"])[0]))
        numeric = (pair[0] - pair[1]) / (2 * step)
        exact = np.concatenate(slope if name == "release" else [s[:, col] for s in sens])
        # the release's column is -alpha interpolated linearly (not the Hermite's exact slope): O(h)
        tolerance = 1e-2 if name == "release" else 2e-5
        np.testing.assert_allclose(exact, numeric, rtol=0, atol=tolerance * np.abs(exact).max(), err_msg=name)


def _explicit_normal_equations(coef, phi0, omega0, at, observed, sigma, release_s, wrt, release_column,
                               timing_column, inputs):  # fmt: skip
    """The reference: the whole Jacobian from rates_at's sensitivities and slopes, then BLAS."""
    (r1, r2), (s1, s2), (t1, t2) = fast_planar.rates_at(
        coef, phi0, omega0, at, 0.01, release_s=release_s, wrt=wrt, inputs=inputs
    )
    blocks = []
    for node, (s, t) in enumerate(((s1, t1), (s2, t2))):
        cols = (
            [s]
            + ([t[:, None]] if release_column else [])
            + ([(-t if node else 0.0 * t)[:, None]] if timing_column else [])
        )
        blocks.append(np.hstack(cols) / sigma[node])
    jac = np.vstack(blocks)
    r = np.concatenate([(r1 - observed[0]) / sigma[0], (r2 - observed[1]) / sigma[1]])
    return jac.T @ jac, jac.T @ r, float(r @ r)


@pytest.mark.parametrize("start", ["release with timing", "moving", "driven release", "driven at the stages"])
def test_normal_equations_at_equal_the_explicit_jacobians_products(start):
    """normal_equations_at sums J^T J, J^T r and r.r in one pass; they equal the products of the
    n x P Jacobian assembled from rates_at (sensitivities, release slope, M2's timing column) to
    1e-12 relative, instants before the release included (rate 0, a zero row)."""
    rng = np.random.default_rng(21)
    coef = fast_planar.coefficients([FRICTION])
    at = (np.sort(rng.uniform(0.0, 6.0, 500)), np.sort(rng.uniform(0.0, 6.0, 450)))
    sigma = np.array([0.004, 0.007])
    phi0, omega0, release_s, inputs = (0.5, 0.1), (0.0, 0.0), 0.037, None
    wrt = ("b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m", "phi1_0", "phi2_0")
    release_column = timing_column = True
    if start == "moving":
        omega0, release_s, release_column, timing_column = (0.8, -0.3), 0.0, False, False
        wrt = (*wrt, "omega1_0", "omega2_0")
    if start == "driven release":
        steps = np.arange(700) * 0.01
        inputs = np.stack([0.2 * np.sin(5 * steps), 0.1 * np.cos(3 * steps), 0.4 * np.sin(2 * steps), 0 * steps], 1)
    if start == "driven at the stages":  # (700, NSTAGE, 4): each step's start, midpoint and end
        t = np.arange(700)[:, None] * 0.01 + np.array([0.0, 0.005, 0.01])
        inputs = np.stack([0.2 * np.sin(5 * t), 0.1 * np.cos(3 * t), 0.4 * np.sin(2 * t), 0.5 * np.cos(t)], -1)
    truth = fast_planar.rates_at(coef, (0.49, 0.11), omega0, at, 0.01, release_s=0.03, inputs=inputs)[0]
    observed = tuple(r + rng.normal(0.0, s, len(r)) for r, s in zip(truth, sigma, strict=True))
    args = (coef, phi0, omega0, at, observed, sigma)
    flags = {"release_column": release_column, "timing_column": timing_column, "inputs": inputs}
    jtj, jtr, rr = fast_planar.normal_equations_at(*args, 0.01, release_s=release_s, wrt=wrt, **flags)
    ref_jtj, ref_jtr, ref_rr = _explicit_normal_equations(*args, release_s, wrt, **flags)
    assert jtj.shape == (len(wrt) + release_column + timing_column,) * 2
    assert np.count_nonzero(at[0] < release_s) > 0 or start == "moving"
    scale = np.sqrt(np.outer(np.diag(ref_jtj), np.diag(ref_jtj)))  # entries relative to their columns' norms
    np.testing.assert_allclose(jtj / scale, ref_jtj / scale, rtol=0, atol=1e-12)
    bound = np.sqrt(np.diag(ref_jtj) * ref_rr)  # |J^T r| per column (Cauchy-Schwarz)
    assert np.all(np.abs(jtr - ref_jtr) <= 1e-12 * bound), (jtr - ref_jtr) / bound
    assert rr == pytest.approx(ref_rr, rel=1e-12)
    no_columns = fast_planar.normal_equations_at(*args, 0.01, release_s=release_s, inputs=inputs)
    assert no_columns[0].shape == (0, 0) and no_columns[2] == pytest.approx(ref_rr, rel=1e-12)


def test_one_undriven_run_has_the_batch_kernels_bits():
    """A single undriven run goes through ``single.integrate_one_undriven`` (compiled in a quarter of
    the batch kernel's time); its rows equal the same member's in a batch run by the serial batch
    kernel and by the parallel one, bit for bit (dry friction, large angles, every 3rd step kept)."""
    from pendsim_mj.engines.fast_planar import batch
    from pendsim_mj.engines.fast_planar.closed_form import coefficients

    params = [DEFAULT_PARAMS.with_overrides(friction1_n_m=2e-4, b2_n_m_s=1e-3), DEFAULT_PARAMS, DEFAULT_PARAMS]
    k = coefficients(params)
    y0 = np.array([[2.5, 0.3, -1.0], [-0.4, 0.0, 1.2], [1.0, 0.0, 0.0], [0.0, 3.0, -2.0], [0.0, 0.0, 0.0]])
    none = np.zeros((0, 3, 4, 3))
    one = batch._run(k[:, :1], y0[:, :1], none[..., :1], 0, 900, 0.01, 3, 1)
    serial = batch._run(k, y0, none, 0, 900, 0.01, 3, 1)  # one chunk: the serial batch kernel
    parallel = batch._run(np.repeat(k, 40, axis=1), np.repeat(y0, 40, axis=1), np.repeat(none, 40, axis=3),
                          0, 900, 0.01, 3, 2)  # fmt: skip
    assert one.shape == (301, 5, 1)
    np.testing.assert_array_equal(one[:, :, 0], serial[:, :, 0])
    np.testing.assert_array_equal(one[:, :, 0], parallel[:, :, 0])
