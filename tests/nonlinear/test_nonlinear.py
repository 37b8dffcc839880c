"""Nonlinear-dynamics analyses on the MuJoCo model, each checked against something independent:
the linearised modes of the reference equations, free simulations by the reference solver,
stepped-sine simulation against continuation, the Mathieu-type limit of parametric excitation,
Floquet exponents against Lyapunov exponents, and signals with known phase relations."""

import math

import numpy as np
import pytest

from pendsim_mj.engines import reference
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.analysis import zero_crossing_hz
from pendsim_mj.nonlinear import (
    backbone,
    compare_with_branch,
    continue_response,
    largest_lyapunov,
    orbit_at,
    phase_locking,
    poincare_sweep,
    stepped_sine,
    tongues,
)
from pendsim_mj.nonlinear.continuation import Point, Settings, continue_branch, newton
from pendsim_mj.nonlinear.response import detect_bifurcations
from pendsim_mj.rig.drives import Drive, Sine
from pendsim_mj.rig.params import DEFAULT_PARAMS

DEG = math.pi / 180
# Ten times the default damping (amplitude to 20 % in 12 s): steady states settle in tens of
# periods, so the response tests stay short; the physics is the same.
DAMPED = DEFAULT_PARAMS.with_overrides(b1_n_m_s=10 * DEFAULT_PARAMS.b1_n_m_s, b2_n_m_s=10 * DEFAULT_PARAMS.b2_n_m_s)


def _linearised_hz(params) -> np.ndarray:
    """Undamped natural frequencies from the eigenvalues of the reference's state Jacobian at
    rest, by central differences (as tests/engines/test_physics.py does), ascending."""
    k = reference._coefficients([params.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0)])
    jac = np.zeros((4, 4))
    for j in range(4):
        step = np.zeros((5, 1))
        step[j] = 1e-6
        jac[:, j] = (reference.derivative(step, k) - reference.derivative(-step, k))[:4, 0] / 2e-6
    lam = np.linalg.eigvals(jac)
    return np.sort(lam.imag[lam.imag > 0]) / (2 * math.pi)


@pytest.fixture(scope="module")
def backbone_mode1():
    return backbone(DEFAULT_PARAMS, 1, max_amplitude_rad=75 * DEG, steps_per_period=64)


def test_backbone_of_mode_1_starts_at_the_linearised_frequency(backbone_mode1):
    b = backbone_mode1
    linear = _linearised_hz(DEFAULT_PARAMS)[0]
    assert np.max(b.amplitude_rad[0]) < 0.3 * DEG  # the first point is at small amplitude
    assert abs(b.frequency_hz[0] - linear) / linear < 1e-4, (b.frequency_hz[0], linear)


def test_backbone_of_mode_1_equals_the_free_simulation_frequency_at_every_amplitude(backbone_mode1):
    b = backbone_mode1
    assert np.max(b.amplitude_rad[-1]) >= 75 * DEG and b.end_reason == "amplitude limit"
    assert len(b.frequency_hz) >= 10
    # the pendulum softens: the frequency falls with amplitude (by ~10 % at 75 deg)
    assert np.all(np.diff(b.frequency_hz) < 0) and b.frequency_hz[-1] < 0.92 * b.frequency_hz[0]
    # the analysis' own check (MuJoCo, 10 ms) at every point, and the orbit closes over a whole
    # period (only half a period is imposed; RK4 is not exactly time-reversible, so the residual is
    # O(dt^4): 1.2e-6 at 64 steps per period and 75 deg, 16x less at 128)
    assert np.max(b.free_relative_difference) < 1e-4
    assert np.max(b.periodicity_residual) < 1e-5
    assert np.all(b.stable)
    # independently: the reference solver started on some computed orbits
    picks = [0, len(b.frequency_hz) // 2, len(b.frequency_hz) - 1]
    undamped = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0)
    tr = reference.solve_batch(undamped, b.phi0_rad[picks], (0.0, 0.0), 12.0)
    for row, i in enumerate(picks):
        measured = zero_crossing_hz(tr.t_s, tr.phi_rad[row, :, 0])
        assert abs(measured - b.frequency_hz[i]) / b.frequency_hz[i] < 1e-4, (i, measured, b.frequency_hz[i])


def test_backbone_of_mode_2_starts_at_the_second_linearised_frequency_and_closes():
    b = backbone(DEFAULT_PARAMS, 2, max_amplitude_rad=20 * DEG, steps_per_period=64)
    linear = _linearised_hz(DEFAULT_PARAMS)[1]
    assert abs(b.frequency_hz[0] - linear) / linear < 1e-4
    assert np.argmax(b.amplitude_rad[-1]) == 1  # mode 2 swings M2 most
    assert np.max(b.free_relative_difference) < 1e-4 and np.max(b.periodicity_residual) < 1e-5


@pytest.fixture(scope="module")
def response():
    """A softening resonance of mode 1 driven hard enough to fold: stepped sine up and down over
    both jumps, and the continued branch."""
    drive = Drive(torque_m1=Sine(0.05, 0.8))
    branch = continue_response(
        DAMPED, drive, 0.7, 0.95, steps_per_period=64, settings=Settings(ds=0.05, ds_max=0.3, max_points=300)
    )
    sweeps = stepped_sine(DAMPED, drive, np.linspace(0.74, 0.86, 13), steps_per_period=64)
    return drive, branch, sweeps


def test_continuation_reports_the_two_folds_of_a_softening_resonance(response):
    _, branch, _ = response
    folds = branch.folds()
    assert len(folds) == 2, branch.bifurcations
    upper, lower = sorted(folds, key=lambda b: -b.frequency_hz)
    assert 0.80 < upper.frequency_hz < 0.83 and 0.75 < lower.frequency_hz < 0.78
    # the middle branch, between the folds, is the unstable one (a real multiplier beyond +1)
    unstable = ~branch.stable
    assert np.count_nonzero(unstable) >= 5
    assert np.all(np.flatnonzero(unstable) == np.arange(upper.index + 1, lower.index + 1))
    f = branch.frequency_hz[unstable]
    assert np.all((f > lower.frequency_hz - 1e-6) & (f < upper.frequency_hz + 1e-6))
    assert np.all(np.abs(branch.multipliers[unstable, 0].imag) < 1e-9)
    assert np.all(branch.multipliers[unstable, 0].real > 1)
    assert np.max(branch.residual) < 1e-9
    assert branch.end_reason == "end of the frequency range"


def test_each_fold_is_the_turning_point_where_two_orbits_meet(response):
    drive, branch, _ = response
    for fold in branch.folds():
        assert fold.refined and fold.frequency_tol_hz < 1e-9 and fold.amplitude_tol_rad[0] < 1e-7
        i = fold.index
        beyond = fold.frequency_hz - branch.frequency_hz[i] > 0  # the frequency turns back at a maximum
        inside = fold.frequency_hz + (-1e-5 if beyond else 1e-5)
        # independently, by Newton at fixed frequencies from the branch points either side: 1e-5 Hz
        # inside the fold two orbits whose amplitudes straddle the fold's (their midpoint is it to
        # O(1e-5 Hz): 0.002 deg here), 1e-5 Hz outside none
        amps = [orbit_at(DAMPED, drive, inside, x, steps_per_period=64).amplitude_rad[0] for x in branch.x0[i : i + 2]]
        assert min(amps) < fold.amplitude_rad[0] < max(amps) and max(amps) - min(amps) > 0.1 * DEG
        assert np.mean(amps) == pytest.approx(fold.amplitude_rad[0], abs=0.01 * DEG)
        with pytest.raises(ParameterError, match="Newton did not converge"):
            orbit_at(DAMPED, drive, 2 * fold.frequency_hz - inside, branch.x0[i], steps_per_period=64)


def test_stepped_sine_and_continuation_agree_to_1_percent_on_the_stable_branches(response):
    drive, branch, sweeps = response
    up, down = sweeps
    assert np.all(up.settled) and np.all(down.settled)
    # hysteresis: the up sweep jumps up at the upper fold, the down sweep down at the lower one
    upper, lower = sorted((b.frequency_hz for b in branch.folds()), reverse=True)
    jump_up = np.argmax(np.diff(up.amplitude_rad[:, 0]))
    jump_down = np.argmax(-np.diff(down.amplitude_rad[:, 0]))
    assert up.frequency_hz[jump_up] < upper < up.frequency_hz[jump_up + 1]
    assert down.frequency_hz[jump_down + 1] < lower < down.frequency_hz[jump_down]
    for sweep in sweeps:
        agreement = compare_with_branch(DAMPED, drive, sweep, branch)
        assert np.all(np.isfinite(agreement.branch_rad)), sweep.direction
        assert agreement.max_relative_difference < 0.01, (sweep.direction, agreement.relative_difference)


def test_a_parametric_tongue_at_small_level_matches_the_mathieu_boundary_to_2_percent():
    # principal tongue of mode 1 (2 f1 = 1.754 Hz), levels up to eps = 0.05 (0.55 m/s^2 ~ 4.5 mm)
    f = np.linspace(1.735, 1.775, 9)
    result = tongues(DEFAULT_PARAMS, f, 0.55, levels=6, steps_per_period=64)
    analytic = result.analytic_m_s2[0]
    inside = analytic < 0.55
    assert inside.sum() >= 5
    np.testing.assert_array_equal(np.isfinite(result.boundary_m_s2), inside)
    np.testing.assert_allclose(result.boundary_m_s2[inside], analytic[inside], rtol=0.02)
    # the threshold at the tongue's tip: damping keeps rest stable below it
    assert np.nanmin(result.boundary_m_s2) > 0.1
    assert 2 * result.linear_frequency_hz[0] == pytest.approx(1.7544, abs=1e-3)


def test_inside_the_tongue_the_response_is_period_2_and_outside_rest_stays():
    diagram = poincare_sweep(
        DAMPED,
        Drive(pivot_z=Sine(5.0, 1.75)),
        [1.45, 1.75],
        steps_per_period=64,
        transient_periods=300,
        sample_periods=8,
        x0=(0.01, 0.0, 0.0, 0.0),
        directions=("up",),
    )
    sweep = diagram.sweeps[0]
    assert list(sweep.period) == [1, 2]
    assert np.max(np.abs(sweep.samples[0, :, :2])) < 1e-6  # outside: back to rest
    alternating = sweep.samples[1, :, 0]
    assert np.all(np.abs(alternating) > 20 * DEG) and np.all(alternating[1:] * alternating[:-1] < 0)


def test_the_lyapunov_exponent_of_a_stable_orbit_is_its_largest_floquet_exponent():
    drive = Drive(torque_m1=Sine(0.01, 0.8))
    n = 64
    orbit = orbit_at(DAMPED, drive, 0.8, np.zeros(4), steps_per_period=n)
    assert orbit.stable and orbit.residual < 1e-10
    floquet = math.log(np.max(np.abs(orbit.multipliers))) * 0.8
    result = largest_lyapunov(
        DAMPED, drive, x0=orbit.x0, duration_s=150 / 0.8, transient_s=0.0, interval_s=1 / 0.8, dt_s=1 / (0.8 * n),
        members=4,
    )  # fmt: skip
    assert result.exponent_per_s < 0
    assert result.exponent_per_s == pytest.approx(floquet, rel=0.02)
    assert result.converged and abs(result.exponent_per_s - floquet) <= result.uncertainty_per_s
    assert len(result.running_per_s) == 150 and result.running_per_s[-1] == pytest.approx(floquet, rel=0.05)


def test_a_hard_driven_rig_is_chaotic_and_the_free_conservative_rig_is_not():
    chaotic = largest_lyapunov(
        DEFAULT_PARAMS, Drive(torque_m1=Sine(0.5, 0.6)), duration_s=80.0, transient_s=20.0, members=3
    )
    assert chaotic.exponent_per_s - chaotic.uncertainty_per_s > 0.3
    free = largest_lyapunov(
        DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0),
        None,
        x0=(20 * DEG, 0.0, 0.0, 0.0),
        duration_s=200.0,
        transient_s=0.0,
        members=2,
    )
    # regular motion: separation grows at most linearly (ln t / t is left: 0.01 1/s here)
    assert free.converged and abs(free.exponent_per_s) + free.uncertainty_per_s < 0.02


def test_phase_locking_of_signals_with_known_phases():
    t = np.arange(0, 100, 0.01)
    locked = phase_locking(t, np.sin(2 * math.pi * 0.9 * t), 0.3 * np.sin(2 * math.pi * 0.9 * t + 1.0))
    assert locked.index > 0.999 and locked.frequency_ratio == pytest.approx(1.0, abs=1e-3)
    assert np.mean(locked.phase_difference_rad) == pytest.approx(-1.0, abs=0.01)
    drifting = phase_locking(t, np.sin(2 * math.pi * 0.9 * t), np.sin(2 * math.pi * math.sqrt(2) * 0.9 * t))
    assert drifting.index < 0.1 and drifting.frequency_ratio == pytest.approx(1 / math.sqrt(2), rel=1e-3)
    two_to_one = phase_locking(t, np.sin(2 * math.pi * 1.6 * t), np.sin(2 * math.pi * 0.8 * t), ratio=(2, 1))
    assert two_to_one.index > 0.999 and two_to_one.nearest_ratio == (2, 1)


def test_uncoupled_pendulums_do_not_lock_and_coupled_ones_do():
    # M2 released and free, M1 driven off its own frequency
    drive = Drive(torque_m1=Sine(0.02, 0.6))
    uncoupled = DEFAULT_PARAMS.with_overrides(c1_n_m=0.0, b1_n_m_s=0.0, b2_n_m_s=0.0)
    tr = simulate(uncoupled, (0.0, 10 * DEG), (0.0, 0.0), 100.0, drive=drive)
    lock = phase_locking(tr.t_s, tr.phi_rad[:, 0], tr.phi_rad[:, 1])
    f2 = _linearised_hz(uncoupled)  # with c1 = 0 the modes are M1 alone and M2 alone
    assert lock.index < 0.3
    assert lock.f2_hz == pytest.approx(max(f2), rel=0.01)
    # coupled and damped, in steady state: M2 follows the drive on M1, 1:1 locked
    drive_m1 = Drive(torque_m1=Sine(0.01, 1.1))
    (sweep,) = stepped_sine(DAMPED, drive_m1, [1.1], steps_per_period=64, directions=("up",), measure_periods=20)
    assert sweep.locking_index[0] > 0.99 and sweep.frequency_ratio[0] == pytest.approx(1.0, abs=1e-3)


def test_bifurcations_are_classified_by_the_multiplier_that_crosses():
    f = np.linspace(1.0, 2.0, 5)
    amp = np.zeros((5, 2))
    tangent = np.ones(5)
    # a real multiplier passes -1 between points 1 and 2, at 3/4 of the way
    pd = np.array([[-0.5, 0.2], [-0.9, 0.2], [-1.1, 0.2], [-1.3, 0.2], [-1.5, 0.2]], dtype=complex)
    (found,) = detect_bifurcations(f, amp, pd, tangent)
    assert found.kind == "period_doubling" and found.index == 1
    assert found.frequency_hz == pytest.approx(1.25 + 0.25 * 0.5)
    # a complex pair leaves the unit circle
    r = np.array([0.8, 0.9, 0.95, 1.05, 1.1])
    ns = np.stack([r * np.exp(0.7j), r * np.exp(-0.7j)], axis=1)
    (found,) = detect_bifurcations(f, amp, ns, tangent)
    assert found.kind == "neimark_sacker" and found.index == 2
    # the frequency turns back: a fold
    folded = np.array([1.0, 1.2, 1.3, 1.2, 1.0])
    kinds = [b.kind for b in detect_bifurcations(folded, amp, np.full((5, 2), 0.5 + 0j), np.array([1, 1, 1, -1, -1]))]
    assert kinds == ["fold"]


def test_pseudo_arclength_continuation_goes_around_a_circle_through_its_turning_points():
    # G(x, y) = x^2 + y^2 - 1: the branch turns back in x at (+-1, 0)
    def system(u):
        return np.array([u[0] ** 2 + u[1] ** 2 - 1]), np.array([[2 * u[0], 2 * u[1]]]), None

    start = newton(system, np.array([0.0, 0.9]), scale=np.ones(2), fixed=0)
    assert start.u == pytest.approx([0.0, 1.0], abs=1e-12)
    start = Point(start.u, np.array([1.0, 0.0]), start.residual, start.iterations, None)
    points, why = continue_branch(
        system, start, scale=np.ones(2), settings=Settings(ds=0.1, ds_max=0.2, max_points=200),
        stop=lambda p: p.u[0] < 0 and p.u[1] > 0,
    )  # fmt: skip
    u = np.array([p.u for p in points])
    assert why == "stop"
    np.testing.assert_allclose(np.hypot(u[:, 0], u[:, 1]), 1.0, atol=1e-10)
    assert u[:, 0].max() > 0.99 and u[:, 0].min() < -0.99 and u[:, 1].min() < -0.99  # all the way round


def test_analyses_refuse_drives_they_cannot_sweep():
    with pytest.raises(ParameterError, match="sine drives; torque_m1 is a Chirp"):
        from pendsim_mj.rig.drives import Chirp

        continue_response(DAMPED, Drive(torque_m1=Chirp(0.01, 0.5, 1.0, 10.0)), 0.7, 0.9)
    with pytest.raises(ParameterError, match="share one frequency"):
        stepped_sine(DAMPED, Drive(torque_m1=Sine(0.01, 0.8), torque_m2=Sine(0.01, 0.9)), [0.8])
    with pytest.raises(ParameterError, match="mode must be 1 or 2"):
        backbone(DEFAULT_PARAMS, 3)
