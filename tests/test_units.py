"""Time units (pendsim_mj/units.py): nanoseconds and seconds, checked against exact rational
arithmetic (fractions), not against the code's own formulas."""

from fractions import Fraction

import numpy as np
import pytest

from pendsim_mj.units import NS_PER_S, nanoseconds, seconds, split_ns


@pytest.mark.parametrize("t_ns", [0, 1, 12_500_000, 1_764_000_000_123_456_789, -2_000_000_001])
def test_seconds_is_the_nearest_float_to_the_exact_quotient_within_one_ulp(t_ns):
    exact = Fraction(t_ns, NS_PER_S)
    got = seconds(t_ns)
    assert isinstance(got, float)
    assert abs(Fraction(got) - exact) <= Fraction(np.spacing(abs(float(exact)) or 1e-300))


def test_seconds_of_an_int64_array_is_float64_and_keeps_the_multiplication_bits():
    t_ns = np.array([0, 12_500_000, 1_764_000_000_123_456_789], dtype=np.int64)
    got = seconds(t_ns)
    assert got.dtype == np.float64
    assert np.array_equal(got, t_ns * 1e-9)  # the form every caller used before: same bits


@pytest.mark.parametrize(
    ("t_s", "expected"),
    [(0.0125, 12_500_000), (1.0, NS_PER_S), (-0.5, -500_000_000), (2.5e-9, 2), (3.5e-9, 4), (1e-10, 0)],
)
def test_nanoseconds_rounds_to_the_nearest_and_halves_to_even(t_s, expected):
    assert nanoseconds(t_s) == expected
    assert nanoseconds(np.array([t_s]))[0] == expected


def test_nanoseconds_of_an_array_is_int64():
    assert nanoseconds(np.array([0.1, 0.2])).dtype == np.int64


@pytest.mark.parametrize("t_ns", [0, 1, NS_PER_S - 1, NS_PER_S, 1_764_000_000_123_456_789, -1])
def test_split_ns_gives_whole_seconds_and_a_remainder_below_one_second(t_ns):
    sec, nanosec = split_ns(t_ns)
    assert 0 <= nanosec < NS_PER_S
    assert sec * NS_PER_S + nanosec == t_ns
