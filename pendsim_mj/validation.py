"""Validation metrics of the paper (spec RIG.md section 7) on two series at common instants.

Delta(t) = f_N(t) - f_M(t) (N: numerical/computed, M: measured); IAE = int |Delta| dt and
ISE = int Delta^2 dt by Simpson's rule at the samples' fixed step (and as cumulative curves);
RMS and max |Delta|; the natural frequency of each series by interpolated zero crossings and by
the interpolated spectral peak, with the relative error delta = |f_C - f_M| / f_M.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.integrate import cumulative_simpson, simpson
from scipy.interpolate import CubicSpline

from pendsim_mj.analysis import noise_level, spectral_peak_hz, zero_crossing_hz
from pendsim_mj.errors import ParameterError


@dataclasses.dataclass(frozen=True)
class Comparison:
    """One quantity, computed against measured, over one window.

    Attributes:
      t_s: (n,) common instants (uniform step), s.
      measured, computed, delta: (n,) the series and Delta = computed - measured.
      iae, ise: integral of |Delta| and Delta^2 over the window (Simpson).
      iae_curve, ise_curve: (n,) the same integrals from the window's start to each instant.
      rms, max_abs: of Delta.
      f_measured_hz, f_computed_hz, delta_f: by interpolated zero crossings (the paper's "natural
        frequency"), with a hysteresis band of 4 noise sigmas of the measured series.
      f_measured_fft_hz, f_computed_fft_hz, delta_f_fft: by the interpolated spectral peak.
    """

    t_s: np.ndarray
    measured: np.ndarray
    computed: np.ndarray
    delta: np.ndarray
    iae: float
    ise: float
    iae_curve: np.ndarray
    ise_curve: np.ndarray
    rms: float
    max_abs: float
    f_measured_hz: float
    f_computed_hz: float
    delta_f: float
    f_measured_fft_hz: float
    f_computed_fft_hz: float
    delta_f_fft: float

    def summary(self) -> dict[str, float]:
        """The scalar metrics, for tables and JSON."""
        return {
            "f_measured_hz": self.f_measured_hz,
            "f_computed_hz": self.f_computed_hz,
            "delta_f": self.delta_f,
            "f_measured_fft_hz": self.f_measured_fft_hz,
            "f_computed_fft_hz": self.f_computed_fft_hz,
            "delta_f_fft": self.delta_f_fft,
            "max_abs": self.max_abs,
            "rms": self.rms,
            "iae": self.iae,
            "ise": self.ise,
        }


def resample(t_source_s: np.ndarray, values: np.ndarray, t_target_s: np.ndarray) -> np.ndarray:
    """Values of a smooth series at other instants (cubic spline), along axis 0."""
    t_source_s = np.asarray(t_source_s, dtype=float)
    t_target_s = np.asarray(t_target_s, dtype=float)
    if t_target_s.min() < t_source_s[0] - 1e-9 or t_target_s.max() > t_source_s[-1] + 1e-9:
        raise ParameterError(
            f"cannot resample to {t_target_s.min():.3f}-{t_target_s.max():.3f} s from a series over "
            f"{t_source_s[0]:.3f}-{t_source_s[-1]:.3f} s"
        )
    return CubicSpline(t_source_s, values, axis=0)(t_target_s)


def _frequency(fn, t: np.ndarray, x: np.ndarray) -> float:
    try:
        return fn(t, x)
    except ParameterError:
        return float("nan")


def _detrend(x: np.ndarray, window: int) -> np.ndarray:
    """x minus its centred running mean over ``window`` samples (edges: the nearest full window)."""
    if window < 3 or window >= len(x):
        return x
    kernel = np.ones(window) / window
    mean = np.convolve(x, kernel, mode="valid")
    pad_left = (len(x) - len(mean)) // 2
    mean = np.concatenate([np.full(pad_left, mean[0]), mean, np.full(len(x) - len(mean) - pad_left, mean[-1])])
    return x - mean


def compare(t_s: np.ndarray, measured: np.ndarray, computed: np.ndarray) -> Comparison:
    """All metrics of computed against measured at the same uniformly spaced instants."""
    t = np.asarray(t_s, dtype=float)
    m = np.asarray(measured, dtype=float)
    c = np.asarray(computed, dtype=float)
    if t.ndim != 1 or m.shape != t.shape or c.shape != t.shape:
        raise ParameterError(f"expected three (n,) series, got {t.shape}, {m.shape}, {c.shape}")
    if len(t) < 8:
        raise ParameterError(f"need at least 8 common samples, got {len(t)}")
    step = np.diff(t)
    dx = float(step.mean())
    if np.max(np.abs(step - dx)) > 1e-6 * max(dx, 1e-12) + 1e-12:
        raise ParameterError("the instants must be uniformly spaced (resample first)")
    delta = c - m
    abs_delta = np.abs(delta)
    squared = delta * delta
    # zero crossings with hysteresis at 4 noise sigmas of the measured series (noise near zero
    # would add crossings and raise the measured frequency)
    band = 4.0 * noise_level(m)
    g_m, g_c = spectral_peak_hz(t, m), spectral_peak_hz(t, c)
    # Crossings of the oscillation about its running mean over one period: a decaying swing moves
    # the mean of quantities like r omega^2 + g cos phi, so the global mean would miss crossings.
    period = round(1.0 / (g_m * dx)) if g_m > 0 else 0
    f_m = _frequency(lambda tt, xx: zero_crossing_hz(tt, _detrend(xx, period), band), t, m)
    f_c = _frequency(lambda tt, xx: zero_crossing_hz(tt, _detrend(xx, period), band), t, c)
    return Comparison(
        t_s=t,
        measured=m,
        computed=c,
        delta=delta,
        iae=float(simpson(abs_delta, dx=dx)),
        ise=float(simpson(squared, dx=dx)),
        iae_curve=cumulative_simpson(abs_delta, dx=dx, initial=0.0),
        ise_curve=cumulative_simpson(squared, dx=dx, initial=0.0),
        rms=float(np.sqrt(np.mean(squared))),
        max_abs=float(abs_delta.max()),
        f_measured_hz=f_m,
        f_computed_hz=f_c,
        delta_f=abs(f_c - f_m) / f_m if f_m else float("nan"),
        f_measured_fft_hz=g_m,
        f_computed_fft_hz=g_c,
        delta_f_fft=abs(g_c - g_m) / g_m if g_m else float("nan"),
    )
