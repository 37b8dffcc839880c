"""Signal analysis used by the CLI summary and the physics checks: frequencies and decay.

Imports no physics engine. All functions take uniformly sampled series: t_s (n,) in s.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from pendsim_mj.errors import ParameterError


def _check_series(t_s: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(x, dtype=float)
    if t.ndim != 1 or y.shape != t.shape:
        raise ParameterError(f"expected t_s and x of the same shape (n,), got {t.shape} and {y.shape}")
    if len(t) < 8:
        raise ParameterError(f"need at least 8 samples, got {len(t)}")
    return t, y


def noise_level(x: np.ndarray) -> float:
    """A robust estimate of the white-noise sigma of a smooth signal plus noise: the median
    absolute deviation of its second differences / sqrt(6) (the signal's own curvature adds to
    it, so this errs high for coarse sampling)."""
    d2 = np.diff(np.asarray(x, dtype=float), 2)
    if len(d2) == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def spectral_peak_hz(t_s: np.ndarray, x: np.ndarray, max_hz: float = np.inf) -> float:
    """Dominant frequency of x (Hz), below ``max_hz``: the largest peak of its Hann-windowed
    spectrum, refined by a parabola through the log-magnitudes of the three bins around it
    (accuracy well below one bin, 1/duration). The mean is removed first; returns 0.0 for a
    constant signal or when no bin lies below ``max_hz``."""
    t, y = _check_series(t_s, x)
    dt = (t[-1] - t[0]) / (len(t) - 1)
    y = y - y.mean()
    if not np.any(y):
        return 0.0
    nfft = 1 << (8 * len(y) - 1).bit_length()  # zero-pad 8x: finer grid for the parabola
    spectrum = np.abs(np.fft.rfft(y * np.hanning(len(y)), n=nfft))
    top = min(len(spectrum), int(np.ceil(max_hz * nfft * dt))) if np.isfinite(max_hz) else len(spectrum)
    if top < 2:
        return 0.0
    k = int(np.argmax(spectrum[1:top]) + 1)
    if 1 <= k < len(spectrum) - 1:
        a, b, c = np.log(spectrum[k - 1 : k + 2] + 1e-300)
        denom = a - 2 * b + c
        shift = 0.5 * (a - c) / denom if denom != 0 else 0.0
    else:
        shift = 0.0
    return float((k + shift) / (nfft * dt))


def _hysteresis_sign(y: np.ndarray, band: float) -> np.ndarray | None:
    """+1 / -1 per sample: the side of +-band the signal was last on (the first known side
    before that); None if it never leaves the band twice."""
    state = np.where(y > band, 1, np.where(y < -band, -1, 0))
    known = np.flatnonzero(state)
    if len(known) < 2:
        return None
    filled = state[known][np.searchsorted(known, np.arange(len(y)), side="right") - 1]
    filled[: known[0]] = state[known[0]]
    return filled


def zero_crossing_hz(t_s: np.ndarray, x: np.ndarray, hysteresis: float = 0.0) -> float:
    """Mean frequency (Hz) from linearly interpolated upward zero crossings of x - mean(x),
    between the first and the last crossing. With ``hysteresis`` h > 0 a crossing counts only
    once the signal has been below -h and then above +h, so noise near zero adds no crossings
    (each counted crossing is still interpolated where the signal passes zero). Raises
    ParameterError with fewer than 2."""
    t, y = _check_series(t_s, x)
    y = y - y.mean()
    if hysteresis > 0:
        filled = _hysteresis_sign(y, hysteresis)
        if filled is None:
            raise ParameterError("fewer than two upward zero crossings: the series is too short to give a frequency")
        rises = np.flatnonzero((filled[:-1] == -1) & (filled[1:] == 1)) + 1  # first sample above +h
        below = np.flatnonzero(y < 0)
        last_negative = below[np.searchsorted(below, rises, side="right") - 1]  # last sample below 0 before it
        idx = last_negative
    else:
        idx = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    if len(idx) < 2:
        raise ParameterError("fewer than two upward zero crossings: the series is too short to give a frequency")
    crossings = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])
    return float((len(crossings) - 1) / (crossings[-1] - crossings[0]))


def peak_amplitudes(t_s: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The amplitude of each half-cycle: the largest |x| between consecutive zero crossings
    (crossings counted with a hysteresis of 4 noise sigmas, so noise near zero makes no extra
    half-cycles), refined by a parabola through the sample and its neighbours. A half-cycle whose
    largest |x| is at its own edge (a release from an extreme, a record cut mid-swing) has no
    peak inside and is skipped. Returns two (k,) arrays: times (s) and amplitudes."""
    t, y = _check_series(t_s, x)
    band = 4.0 * noise_level(y)
    filled = _hysteresis_sign(y, band)
    if filled is None:
        return np.zeros(0), np.zeros(0)
    edges = np.flatnonzero(filled[1:] != filled[:-1]) + 1  # where a half-cycle begins
    bounds = np.concatenate([[0], edges, [len(y)]])
    a = np.abs(y)
    times, amps = [], []
    for lo, hi in itertools.pairwise(bounds):
        i = lo + int(np.argmax(a[lo:hi]))
        if i in (lo, hi - 1):
            continue  # at the edge of its half-cycle: the extreme is not inside it (a start or an end)
        left, mid, right = a[i - 1], a[i], a[i + 1]
        denom = left - 2 * mid + right
        shift = 0.5 * (left - right) / denom if denom != 0 else 0.0
        times.append(t[i] + shift * (t[1] - t[0]))
        amps.append(mid - 0.25 * (left - right) * shift)
    return np.asarray(times), np.asarray(amps)


def log_decrement_damping(
    t_s: np.ndarray, phi_rad: np.ndarray, inertia_kg_m2: float, window_s: float = 120.0
) -> tuple[float, float, float, float]:
    """The paper's damping identification b = 2 J ln(A0 / AT) / t1 from a free decay.

    A0 is the first amplitude peak of |phi| and AT the last peak at most ``window_s`` after it;
    t1 is the time between them (the paper's t1 = 120 s).

    Returns:
      (b_n_m_s, a0_rad, at_rad, t1_s).
    """
    if not (math.isfinite(inertia_kg_m2) and inertia_kg_m2 > 0):
        raise ParameterError(f"inertia_kg_m2 must be > 0, got {inertia_kg_m2}")
    if not (math.isfinite(window_s) and window_s > 0):
        raise ParameterError(f"window_s must be > 0 s, got {window_s}")
    tp, ap = peak_amplitudes(t_s, phi_rad)
    if len(tp) < 2:
        raise ParameterError("fewer than two amplitude peaks: cannot measure a decay")
    inside = tp <= tp[0] + window_s + 1e-9
    t0, a0 = tp[0], ap[0]
    t_end, a_end = tp[inside][-1], ap[inside][-1]
    t1 = t_end - t0
    if t1 <= 0 or a_end <= 0:
        raise ParameterError("the window holds a single amplitude peak: cannot measure a decay")
    return 2.0 * inertia_kg_m2 * math.log(a0 / a_end) / t1, float(a0), float(a_end), float(t1)
