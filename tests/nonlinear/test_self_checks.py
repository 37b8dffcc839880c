"""The analyses check themselves: a tongue's tip found between the grid's frequencies, a fold at its
turning point, a Lyapunov exponent with an interval that a longer or finer run falls in, each
checked against an independent computation (Mathieu theory, a fine continuation, a long run) and
reported unconverged where the settings cannot decide it."""

import math

import numpy as np
import pytest

from pendsim_mj.nonlinear import linear_modes, mathieu_boundary_m_s2, tongues
from pendsim_mj.nonlinear.tongues import TIP_LEVEL_REL_TOL
from pendsim_mj.rig.params import DEFAULT_PARAMS


def _mathieu_tip(mode: int, around_hz: float) -> tuple[float, float]:
    """(frequency Hz, level m/s^2) of the minimum of the first-order Mathieu boundary, by a fine
    scan of the closed form (1e-6 Hz)."""
    f = np.linspace(around_hz - 0.01, around_hz + 0.01, 20001)
    level = mathieu_boundary_m_s2(linear_modes(DEFAULT_PARAMS), f, mode)
    k = int(np.argmin(level))
    return float(f[k]), float(level[k])


def test_the_tongue_tip_is_found_between_the_grid_frequencies_at_the_mathieu_minimum():
    # 5 frequencies 0.0275 Hz apart: the grid misses the tip (the tongue is ~0.01 Hz wide there)
    result = tongues(DEFAULT_PARAMS, np.linspace(1.70, 1.81, 5), 0.6, levels=4, steps_per_period=64)
    f_tip, a_tip = _mathieu_tip(1, 2 * result.linear_frequency_hz[0])
    tip = result.lowest_tip
    assert tip is not None and tip.near == "2 f1" and tip.converged and not tip.at_edge
    # Mathieu's first-order tip (eps ~ 0.01 here: second-order terms ~1e-4)
    assert tip.level_m_s2 == pytest.approx(a_tip, rel=1e-3)
    assert tip.frequency_hz == pytest.approx(f_tip, abs=1e-4)
    assert tip.level_tol_m_s2 <= TIP_LEVEL_REL_TOL * tip.level_m_s2
    assert abs(tip.level_m_s2 - a_tip) <= tip.level_tol_m_s2 + 2e-5  # the stated tolerance holds
    assert np.nanmin(result.boundary_m_s2) > 1.005 * a_tip  # what the grid alone gives: too high


def test_a_tongue_tip_at_too_few_steps_per_period_is_reported_unconverged():
    result = tongues(DEFAULT_PARAMS, np.linspace(1.74, 1.77, 3), 0.3, levels=2, steps_per_period=32)
    tip = result.lowest_tip
    assert tip is not None and not tip.converged
    # 32 and 64 steps per period differ by more than the tolerance, and the 64-step tip is closer
    f_tip, a_tip = _mathieu_tip(1, 1.7544)
    assert tip.level_tol_m_s2 > TIP_LEVEL_REL_TOL * tip.level_m_s2
    assert abs(tip.level_m_s2 - a_tip) < abs(tip.level_n_m_s2 - a_tip)
    assert math.isfinite(tip.frequency_hz) and abs(tip.frequency_hz - f_tip) < 1e-4


def _independent_exponent_per_s(params, phi0_deg: float, members: int, duration_s: float) -> tuple[float, float]:
    """The largest Lyapunov exponent by another implementation: the compiled planar engine's
    Benettin pairs (unscaled state norm, renormalised every 10 s, the mean over the whole run)
    from ``members`` releases within 1e-4 rad of phi0: (ensemble mean, 95 % half-width), 1/s."""
    from scipy.special import stdtrit

    from pendsim_mj.engines import fast_planar

    rng = np.random.default_rng(7)
    phi0 = np.radians([phi0_deg, 0.0]) + 1e-4 * rng.uniform(-1, 1, (members, 2))
    coef = fast_planar.coefficients([params] * members)
    steps = round(duration_s / 0.01)
    running = fast_planar.lyapunov(coef, phi0, np.zeros((members, 2)), steps, 0.01, renormalise_every=1000,
                                   separation=1e-9)  # fmt: skip
    each = running[-1]
    return float(np.mean(each)), float(stdtrit(members - 1, 0.975) * np.std(each, ddof=1) / math.sqrt(members))


def test_a_chaotic_release_is_reported_unconverged_with_an_interval_that_holds_a_long_run():
    # the undamped rig released at 170 deg: chaotic, with sticky regular islands; single runs of
    # 600 s give 0.03 to 0.16 1/s
    from pendsim_mj.nonlinear import largest_lyapunov

    undamped = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0)
    short = largest_lyapunov(undamped, None, x0=(math.radians(170), 0.0, 0.0, 0.0), duration_s=150.0,
                             transient_s=50.0, members=4)  # fmt: skip
    assert not short.converged and short.failed_check == "spread"
    assert short.uncertainty_per_s > short.tolerance_per_s and short.needed_duration_s > 150.0
    # the interval holds an independent estimate 24 times longer in all (16 runs of 900 s)
    reference, reference_half_width = _independent_exponent_per_s(undamped, 170.0, 16, 900.0)
    assert 0.05 < reference < 0.15 and reference_half_width < 0.03
    assert abs(short.exponent_per_s - reference) <= short.uncertainty_per_s
    assert short.uncertainty_per_s < 0.2  # and says something: the motion is chaotic
    assert short.exponent_per_s - short.uncertainty_per_s > -0.05
