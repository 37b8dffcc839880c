"""The streaming Ljung-Box test of the live twin's innovations against the whole-series test that
identify applies to its residuals, its p-value's distribution on white noise, and its memory."""

from __future__ import annotations

import numpy as np
import pytest

from pendsim_mj.estimation.planar_fit import ljung_box_p
from pendsim_mj.twin.whiteness import Whiteness


@pytest.mark.parametrize("n", [230, 5000])
@pytest.mark.parametrize("coloured", [0.0, 0.1])
def test_the_running_sums_give_the_whole_series_p_value(n, coloured):
    rng = np.random.default_rng(n)
    x = rng.standard_normal(n) + 0.7  # a mean: the centring matters
    x[1:] += coloured * x[:-1]
    w = Whiteness()
    for v in x:
        w.add(v)
    assert w.p_value() == pytest.approx(ljung_box_p(x), rel=1e-9, abs=1e-15)
    rho = w.autocorrelation()
    centred = x - x.mean()
    assert rho[0] == pytest.approx(float(centred[:-1] @ centred[1:] / (centred @ centred)), rel=1e-9)


def test_too_few_values_give_no_p_value_and_non_finite_values_are_left_out():
    w = Whiteness()
    for v in np.random.default_rng(0).standard_normal(150):
        w.add(v)
    w.add(float("nan"))
    assert w.count == 150
    assert np.isnan(w.p_value())


def test_on_white_noise_one_run_in_a_hundred_fails_at_p_001():
    """Under whiteness the p-value is uniform: over 400 white series of 600 values, the share below
    0.01 is within its binomial 99.9 % range (0-4.2 %) and the share below 0.5 near one half."""
    rng = np.random.default_rng(7)
    p = []
    for _ in range(400):
        w = Whiteness()
        for v in rng.standard_normal(600):
            w.add(v)
        p.append(w.p_value())
    p = np.array(p)
    assert np.mean(p < 0.01) <= 0.042
    assert 0.40 < np.mean(p < 0.5) < 0.60


def test_its_memory_does_not_grow_with_the_series():
    w = Whiteness()
    for v in np.random.default_rng(1).standard_normal(20_000):
        w.add(v)
    assert len(w._first) == w.lags and len(w._last) == w.lags and w._products.shape == (w.lags + 1,)
