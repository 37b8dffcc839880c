"""Synchronisation of the two pendulums: phase-locking index and frequency ratio.

Each signal's phase is that of its analytic signal (``scipy.signal.hilbert`` of the signal minus
its mean), unwrapped. For an n:m ratio the locking index is the mean resultant length

    R = | mean exp(i (m theta1 - n theta2)) |

(1: the phase difference m theta1 - n theta2 is constant, locked; near 0: it drifts through
every value). The frequency ratio is the ratio of the mean phase slopes (least squares), i.e. of
the mean frequencies. A tenth of the window is cut at each end (Hilbert edge effects).
"""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import hilbert

from pendsim_mj.errors import ParameterError


@dataclasses.dataclass(frozen=True)
class PhaseLocking:
    """index: the n:m locking index R in [0, 1]. frequency_ratio: f1 / f2. f1_hz, f2_hz: mean
    frequencies. ratio: (n, m) the index was computed for. nearest_ratio: (p, q) the small-integer
    fraction (denominator <= 6) closest to f1/f2. phase_difference_rad: (k,) m theta1 - n theta2
    over the window used. t_s: (k,) its times."""

    index: float
    frequency_ratio: float
    f1_hz: float
    f2_hz: float
    ratio: tuple[int, int]
    nearest_ratio: tuple[int, int]
    phase_difference_rad: NDArray[np.float64]
    t_s: NDArray[np.float64]


def phases_rad(x: ArrayLike) -> NDArray[np.float64]:
    """Unwrapped phase of the analytic signal of x - mean(x), rad."""
    y = np.asarray(x, dtype=float)
    return np.unwrap(np.angle(hilbert(y - y.mean())))


def phase_locking(
    t_s: ArrayLike, x1: ArrayLike, x2: ArrayLike, *, ratio: tuple[int, int] = (1, 1), trim: float = 0.1
) -> PhaseLocking:
    """Locking index and frequency ratio of two uniformly sampled signals (module docstring).

    Args:
      t_s: (k,) times, s. x1, x2: (k,) the signals (e.g. phi1, phi2).
      ratio: (n, m) for n:m locking (f1/f2 = n/m): R = |mean exp(i (m theta1 - n theta2))|.
      trim: share of the window cut at each end.
    """
    t = np.asarray(t_s, dtype=float)
    a, b = np.asarray(x1, dtype=float), np.asarray(x2, dtype=float)
    if t.ndim != 1 or a.shape != t.shape or b.shape != t.shape or len(t) < 16:
        raise ParameterError(f"phase_locking needs three (k,) arrays with k >= 16, got {t.shape}, {a.shape}, {b.shape}")
    n, m = ratio
    if n < 1 or m < 1:
        raise ParameterError(f"ratio must be two positive integers, got {ratio}")
    th1, th2 = phases_rad(a), phases_rad(b)
    cut = int(trim * len(t))
    keep = slice(cut, len(t) - cut)
    t, th1, th2 = t[keep], th1[keep], th2[keep]
    diff = m * th1 - n * th2
    index = float(np.abs(np.mean(np.exp(1j * diff))))
    w1 = np.polyfit(t, th1, 1)[0]
    w2 = np.polyfit(t, th2, 1)[0]
    f1, f2 = abs(w1) / (2 * math.pi), abs(w2) / (2 * math.pi)
    freq_ratio = f1 / f2 if f2 > 0 else math.inf
    if math.isfinite(freq_ratio) and freq_ratio > 0:
        frac = Fraction(freq_ratio).limit_denominator(6)
        nearest = (frac.numerator, frac.denominator)
    else:
        nearest = (0, 0)
    return PhaseLocking(index, freq_ratio, f1, f2, (n, m), nearest, diff, t)
