"""Validation metrics against analytic cases: two sinusoids with closed-form IAE and ISE."""

import math

import numpy as np
import pytest

from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.validation import compare, resample

FS = 80.0


def _sinusoids(f_hz=0.87, amplitude=0.5, phase=0.3, periods=40):
    t = np.arange(0, periods / f_hz + 1e-9, 1 / FS)
    measured = amplitude * np.sin(2 * math.pi * f_hz * t)
    computed = amplitude * np.sin(2 * math.pi * f_hz * t + phase)
    return t, measured, computed


def test_iae_ise_rms_and_max_of_a_phase_shift_have_their_closed_forms():
    # Delta = A (sin(x + p) - sin x) = D cos(x + p/2), D = 2 A sin(p/2): over whole periods T
    # ISE = D^2 T / 2, IAE = 2 D T / pi, RMS = D / sqrt(2), max = D
    f, a, p, periods = 0.87, 0.5, 0.3, 40
    t, m, c = _sinusoids(f, a, p, periods)
    duration = t[-1]
    d = 2 * a * math.sin(p / 2)
    r = compare(t, m, c)
    assert r.ise == pytest.approx(d * d * duration / 2, rel=1e-4)
    assert r.iae == pytest.approx(2 * d * duration / math.pi, rel=1e-3)  # |cos| has kinks: Simpson O(h^2) there
    assert r.rms == pytest.approx(d / math.sqrt(2), rel=1e-3)
    assert r.max_abs == pytest.approx(d, rel=1e-3)
    np.testing.assert_allclose(r.delta, c - m)
    assert r.ise_curve[-1] == pytest.approx(r.ise, rel=1e-6) and r.ise_curve[0] == 0
    assert np.all(np.diff(r.iae_curve) >= -1e-12)


def test_iae_of_an_offset_is_offset_times_duration():
    t = np.arange(0, 5 + 1e-9, 1 / FS)
    m = np.sin(3 * t)
    r = compare(t, m, m + 0.02)
    assert r.iae == pytest.approx(0.02 * 5, rel=1e-12)
    assert r.ise == pytest.approx(0.02**2 * 5, rel=1e-12)


def test_frequencies_by_both_methods_and_their_relative_error():
    t = np.arange(0, 120, 1 / FS)
    m = np.sin(2 * math.pi * 0.8736 * t + 0.2)
    c = np.sin(2 * math.pi * 0.8823 * t)
    r = compare(t, m, c)
    assert r.f_measured_hz == pytest.approx(0.8736, rel=1e-5)
    assert r.f_computed_hz == pytest.approx(0.8823, rel=1e-5)
    assert r.f_measured_fft_hz == pytest.approx(0.8736, rel=2e-4)
    assert r.f_computed_fft_hz == pytest.approx(0.8823, rel=2e-4)
    assert r.delta_f == pytest.approx(abs(0.8823 - 0.8736) / 0.8736, rel=1e-3)
    assert r.delta_f_fft == pytest.approx(r.delta_f, rel=0.05)


def test_resample_reproduces_a_smooth_series_between_its_samples():
    t = np.arange(0, 10.001, 0.01)
    x = np.sin(2 * math.pi * 0.9 * t)
    target = np.arange(0.0125, 9.99, 1 / FS)
    np.testing.assert_allclose(resample(t, x, target), np.sin(2 * math.pi * 0.9 * target), atol=1e-7)
    with pytest.raises(ParameterError, match="cannot resample to"):
        resample(t, x, np.array([11.0]))


def test_compare_rejects_mismatched_or_unordered_input():
    t = np.arange(0, 1, 1 / FS)
    with pytest.raises(ParameterError, match="expected three"):
        compare(t, t, t[:-1])
    unordered = t.copy()
    unordered[5] = unordered[3]
    with pytest.raises(ParameterError, match="the instants must increase"):
        compare(unordered, t, t)


def test_metrics_on_gappy_samples_cover_only_the_covered_segments():
    # An offset of 0.02 over 40 periods with 5 % of the samples lost at random and two gaps of
    # 0.5 s: IAE = 0.02 x covered time (nothing integrated across the gaps), the frequency from
    # whole periods inside segments, the cumulative IAE flat over each gap.
    f, periods = 0.87, 40
    t = np.arange(0, periods / f, 1 / FS)
    keep = np.random.default_rng(0).random(len(t)) > 0.05
    keep &= ~((t > 10) & (t < 10.5)) & ~((t > 30) & (t < 30.5))
    t = t[keep]
    m = np.sin(2 * math.pi * f * t)
    r = compare(t, m, m + 0.02, max_gap_s=0.1)
    covered = np.diff(t)[np.diff(t) <= 0.1].sum()
    assert r.covered_s == pytest.approx(covered)
    assert covered < t[-1] - t[0] - 0.9  # the two gaps are not covered
    assert r.iae == pytest.approx(0.02 * covered, rel=1e-9)
    assert r.f_measured_hz == pytest.approx(f, rel=1e-4) and r.delta_f < 1e-9
    assert r.f_measured_fft_hz == pytest.approx(f, rel=2e-3)
    gap = np.flatnonzero(np.diff(t) > 0.1)[0]
    assert r.iae_curve[gap + 1] == pytest.approx(r.iae_curve[gap])  # flat across the gap


def test_a_comparison_without_its_series_keeps_every_metric():
    from pendsim_mj.estimation.validation import SERIES

    t = np.arange(0, 20, 0.01)
    full = compare(t, np.sin(2 * np.pi * t), 1.01 * np.sin(2 * np.pi * 1.001 * t))
    lean = full.without_series(keep=("t_s", "measured"))
    assert lean.summary() == full.summary()
    assert lean.t_s is full.t_s and lean.measured is full.measured
    assert all(len(getattr(lean, name)) == 0 for name in SERIES if name not in ("t_s", "measured"))
