"""Validation metrics of the paper (spec RIG.md section 7) on two series at common instants.

Delta(t) = f_N(t) - f_M(t) (N: numerical/computed, M: measured); IAE = int |Delta| dt and
ISE = int Delta^2 dt by Simpson's rule at the samples' fixed step (and as cumulative curves);
RMS and max |Delta|; the natural frequency of each series by interpolated zero crossings and by
the interpolated spectral peak, with the relative error delta = |f_C - f_M| / f_M.

Real recordings lose samples: the instants may be irregular and have gaps. Everything is then
computed on the *covered segments* only (runs of samples whose spacing never exceeds
``max_gap_s``; ``pendsim_mj.estimation.timing.segments``): Simpson's rule on each segment's own instants,
the cumulative curves flat across gaps, zero crossings and their periods inside segments, and
the spectrum of a uniform grid with the gaps left empty (zero after the mean is removed),
interpolated only inside segments. With uniform gap-free samples this is the plain computation.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection
from typing import Any

import numpy as np
from scipy.integrate import cumulative_simpson, simpson
from scipy.interpolate import CubicSpline

from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.analysis import noise_level, spectral_peak_hz, upward_crossings
from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S, segments


@dataclasses.dataclass(frozen=True)
class Comparison:
    """One quantity, computed against measured, over one window.

    Attributes:
      t_s: (n,) common instants (increasing; gaps allowed), s.
      measured, computed, delta: (n,) the series and Delta = computed - measured (the series
        as given to ``compare``: float32 ones stay float32; the metrics are computed in float64).
      iae, ise: integral of |Delta| and Delta^2 over the window (Simpson).
      iae_curve, ise_curve: (n,) the same integrals from the window's start to each instant.
      rms, max_abs: of Delta.
      f_measured_hz, f_computed_hz, delta_f: by interpolated zero crossings (the paper's "natural
        frequency"), with a hysteresis band of 4 noise sigmas of the measured series.
      f_measured_fft_hz, f_computed_fft_hz, delta_f_fft: by the interpolated spectral peak.
        Both frequencies over the resolved swing (``RESOLVED_SIGMAS``): the whole window unless
        the measured swing sinks into its noise before the end (a long free decay).
      covered_s: time inside covered segments, s (the whole window without gaps).
      measured_std: standard deviation of the measured series (a scale for rms; kept when the
        series are dropped, ``without_series``).
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
    covered_s: float = float("nan")
    measured_std: float = float("nan")

    def without_series(self, keep: Collection[str] = ()) -> Comparison:
        """This comparison with its (n,) series emptied but those named in ``keep`` (of
        ``SERIES``): the metrics of a long window without holding its arrays."""
        empty: dict[str, Any] = {name: np.empty(0) for name in SERIES if name not in keep}
        return dataclasses.replace(self, **empty)

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
            "covered_s": self.covered_s,
        }


SERIES = ("t_s", "measured", "computed", "delta", "iae_curve", "ise_curve")
"""The (n,) series of a Comparison (the rest are its scalar metrics)."""


SPLINE_MARGIN = 64
"""Source samples on each side of a window of targets that its local spline is fitted over
(``resample``): a cubic spline's dependence on a sample decays by 2 - sqrt(3) = 0.27 per knot,
so 64 knots away it is below 1e-36 of it, far below rounding."""


def resample(
    t_source_s: np.ndarray,
    values: np.ndarray,
    t_target_s: np.ndarray,
    *,
    clip_s: tuple[float, float] | None = None,
) -> np.ndarray:
    """Values of a smooth series at other instants (cubic spline, not-a-knot ends), along axis 0.
    Targets are taken ``WINDOW_SAMPLES`` at a time, each window from a spline through its part of
    the source and ``SPLINE_MARGIN`` samples either side: the whole-run spline's values to
    rounding, in memory flat with the run. ``clip_s``: (low, high) s, targets outside taken at
    them (``np.clip``, window by window: no clipped copy of the targets)."""
    t_source_s = np.asarray(t_source_s, dtype=float)
    t_target_s = np.asarray(t_target_s, dtype=float)

    def clipped(t: np.ndarray) -> np.ndarray:
        return t if clip_s is None else np.clip(t, *clip_s)

    first, last = clipped(np.array([t_target_s.min(), t_target_s.max()]))
    if first < t_source_s[0] - 1e-9 or last > t_source_s[-1] + 1e-9:
        raise ParameterError(
            f"cannot resample to {first:.3f}-{last:.3f} s from a series over {t_source_s[0]:.3f}-{t_source_s[-1]:.3f} s"
        )
    n = len(t_target_s)
    if n <= WINDOW_SAMPLES:
        return CubicSpline(t_source_s, values, axis=0)(clipped(t_target_s))
    out = np.empty((n, *np.shape(values)[1:]))
    for a in range(0, n, WINDOW_SAMPLES):
        targets = clipped(t_target_s[a : a + WINDOW_SAMPLES])
        lo, hi = np.searchsorted(t_source_s, [targets.min(), targets.max()])
        lo, hi = max(int(lo) - SPLINE_MARGIN, 0), min(int(hi) + SPLINE_MARGIN, len(t_source_s))
        out[a : a + WINDOW_SAMPLES] = CubicSpline(t_source_s[lo:hi], values[lo:hi], axis=0)(targets)
    return out


def _frequency(fn, *args) -> float:
    try:
        return fn(*args)
    except ParameterError:
        return float("nan")


def _detrend(x: np.ndarray, window: int) -> np.ndarray:
    """x minus its centred running mean over ``window`` samples (edges: the nearest full window)."""
    if window < 3 or window >= len(x):
        return x
    kernel = np.ones(window) / window
    mean = np.convolve(x, kernel, mode="valid")
    pad_left = (len(x) - len(mean)) // 2
    out = np.array(x, dtype=float)  # x minus the mean, each part in place (no padded copy of the mean)
    out[:pad_left] -= mean[0]
    out[pad_left : pad_left + len(mean)] -= mean
    out[pad_left + len(mean) :] -= mean[-1]
    return out


def _detrend_in_time(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """x minus its centred running mean over ``window_s`` seconds, for irregular instants t (the
    time-weighted mean by the trapezoidal rule; edges: the nearest full window)."""
    if window_s <= 0 or t[-1] - t[0] <= window_s:
        return x
    area = np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))])
    centre = np.clip(t, t[0] + window_s / 2, t[-1] - window_s / 2)
    upper = np.interp(centre + window_s / 2, t, area)
    lower = np.interp(centre - window_s / 2, t, area)
    return x - (upper - lower) / window_s


RESOLVED_SIGMAS = 8.0
"""The swing is resolved while the measured series leaves its mean by more than this many noise
sigmas (``analysis.noise_level``): white noise of that sigma practically never does (p < 1e-14)."""
RESOLVED_MARGIN_S = 10.0
"""The frequencies are measured up to this long after the last resolved sample, s."""


def _resolved_end(t: np.ndarray, m: np.ndarray, sigma: float) -> int:
    """Samples (a prefix of t, m (n,)) over which the measured swing is resolved: up to
    ``RESOLVED_MARGIN_S`` after the last one that leaves the series' mean by more than
    ``RESOLVED_SIGMAS`` noise sigmas; all n when none does (a series without a swing) or the
    swing lasts to the end (the usual case)."""
    deviation = m - m.mean()
    beyond = np.flatnonzero(np.abs(deviation, out=deviation) > RESOLVED_SIGMAS * sigma)
    if len(beyond) == 0:
        return len(t)
    return max(int(np.searchsorted(t, t[beyond[-1]] + RESOLVED_MARGIN_S, side="right")), min(len(t), 8))


def _covered_zero_crossing_hz(
    t: np.ndarray, x: np.ndarray, band: float, segs, window: int, dx: float, uniform: bool
) -> float:
    """Mean frequency from upward zero crossings of x about its running mean, counting only the
    periods between crossings in the same covered segment (the paper's "natural frequency")."""
    periods, total = 0, 0.0
    for lo, hi in segs:
        if hi - lo < 3:
            continue
        y = _detrend(x[lo:hi], window) if uniform else _detrend_in_time(t[lo:hi], x[lo:hi], window * dx)
        crossings = upward_crossings(t[lo:hi], y, band)
        if len(crossings) >= 2:
            periods += len(crossings) - 1
            total += float(crossings[-1] - crossings[0])
    if periods == 0:
        raise ParameterError("fewer than two upward zero crossings in one covered segment: no frequency")
    return periods / total


def _uniform_grid(t: np.ndarray, x: np.ndarray, segs, dx: float) -> tuple[np.ndarray, np.ndarray]:
    """x on a uniform grid of step dx: interpolated inside covered segments, its mean in gaps
    (so that the spectrum sees nothing there)."""
    if len(segs) == 1 and np.allclose(np.diff(t), dx, rtol=1e-6, atol=1e-12):
        return t, x
    grid = t[0] + dx * np.arange(int(np.floor((t[-1] - t[0]) / dx + 1e-9)) + 1)
    values = np.full(len(grid), float(x.mean()))
    for lo, hi in segs:
        inside = (grid >= t[lo]) & (grid <= t[hi - 1])
        values[inside] = np.interp(grid[inside], t[lo:hi], x[lo:hi])
    return grid, values


def _integrals(t: np.ndarray, y: np.ndarray, segs) -> tuple[float, np.ndarray]:
    """Simpson's integral of y over the covered segments, and its cumulative curve (flat over
    gaps)."""
    curve = np.zeros(len(t))
    total = 0.0
    for lo, hi in segs:
        if hi - lo >= 2:
            part = cumulative_simpson(y[lo:hi], x=t[lo:hi], initial=0.0)
            part[-1] = simpson(y[lo:hi], x=t[lo:hi])  # the same integral, as the total uses it
            curve[lo:hi] = total + part
            total += float(part[-1])
        else:
            curve[lo:hi] = total
    return total, curve


WINDOW_SAMPLES = 1 << 16
"""Samples whose errors are computed at once when a comparison keeps no curves (``compare`` with
``series`` leaving out the curves): memory flat with the run; the metrics are the whole run's (the
windows share their end samples and hold an even number of intervals, so Simpson's rule adds up to
the whole run's)."""


def _simpson_windows(lo: int, hi: int, size: int = WINDOW_SAMPLES):
    """(a, b) sample ranges covering [lo, hi): consecutive ones share an end sample, each holds
    ``size`` (even) intervals but the last, which holds at least two."""
    a = lo
    while True:
        b = min(a + size + 1, hi)
        if hi - b < 2:  # what would be left is one interval: the last window takes it
            b = hi
        yield a, b
        if b >= hi:
            return
        a = b - 1


def _windowed_errors(t: np.ndarray, m: np.ndarray, c: np.ndarray, segs, uniform: bool, dx: float):
    """(iae, ise, sum of squares, max |Delta|) of Delta = c - m over the covered segments, window
    by window (``WINDOW_SAMPLES``): equal to the whole-run computation."""
    iae = ise = sum_sq = 0.0
    max_abs = 0.0
    for lo, hi in segs:
        for a, b in _simpson_windows(lo, hi):
            delta = c[a:b] - m[a:b]
            abs_delta = np.abs(delta)
            squared = delta * delta
            first = a if a == lo else a + 1  # the shared end sample counts once in the sums
            sum_sq += float(np.sum(squared[first - a :]))
            max_abs = max(max_abs, float(abs_delta.max()))
            if b - a < 2:
                continue
            if uniform:
                iae += float(simpson(abs_delta, dx=dx))
                ise += float(simpson(squared, dx=dx))
            else:
                iae += float(simpson(abs_delta, x=t[a:b]))
                ise += float(simpson(squared, x=t[a:b]))
    return iae, ise, sum_sq, max_abs


def compare(
    t_s: np.ndarray,
    measured: np.ndarray,
    computed: np.ndarray,
    *,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    series: Collection[str] | None = None,
) -> Comparison:
    """All metrics of computed against measured at the same instants (increasing; irregular
    spacing and gaps allowed: see the module docstring).

    Args:
      t_s: (n,) instants, s.
      measured, computed: (n,) the two series there.
      max_gap_s: spacing above which the samples are not integrated or interpolated across, s.
      series: which of the (n,) ``SERIES`` the result keeps (None: all of them; the others are
        empty, as ``Comparison.without_series`` leaves them). Without "delta", "iae_curve" and
        "ise_curve" the errors are computed window by window (``WINDOW_SAMPLES``, memory flat
        with n), with the same metrics.
    """
    keep = set(SERIES) if series is None else set(series)
    t = np.asarray(t_s, dtype=float)
    m = np.asarray(measured, dtype=float)  # float32 series: a float64 copy while the metrics are computed
    c = np.asarray(computed, dtype=float)
    if t.ndim != 1 or m.shape != t.shape or c.shape != t.shape:
        raise ParameterError(f"expected three (n,) series, got {t.shape}, {m.shape}, {c.shape}")
    if len(t) < 8:
        raise ParameterError(f"need at least 8 common samples, got {len(t)}")
    if np.any(t[1:] <= t[:-1]):
        raise ParameterError("the instants must increase")
    segs = segments(t, max_gap_s)
    # the steps' statistics with one (n,) array at a time: a long run's compare starts lean
    step = np.diff(t)
    mean_step = step.mean()
    # the largest |step - mean| without (n,) temporaries (subtraction is monotonic: the same value)
    spread = max(float(step.max() - mean_step), float(mean_step - step.min()))
    short = step <= max_gap_s
    covered = float(step.sum() if short.all() else step[short].sum())  # no copy without gaps
    del short
    dx = float(np.median(step, overwrite_input=True))  # the steps' last use: the median may reorder them
    del step
    uniform = len(segs) == 1 and spread <= 1e-6 * mean_step + 1e-12
    if uniform:
        dx = float(mean_step)
    empty = np.empty(0)
    delta = iae_curve = ise_curve = empty
    if keep & {"delta", "iae_curve", "ise_curve"}:
        delta = c - m
        abs_delta = np.abs(delta)
        squared = delta * delta
        if uniform:
            iae, ise = float(simpson(abs_delta, dx=dx)), float(simpson(squared, dx=dx))
            iae_curve = cumulative_simpson(abs_delta, dx=dx, initial=0.0)
            ise_curve = cumulative_simpson(squared, dx=dx, initial=0.0)
        else:
            iae, iae_curve = _integrals(t, abs_delta, segs)
            ise, ise_curve = _integrals(t, squared, segs)
        sum_sq, max_abs = float(np.sum(squared)), float(abs_delta.max())
        del abs_delta, squared
    else:
        iae, ise, sum_sq, max_abs = _windowed_errors(t, m, c, segs, uniform, dx)
    # zero crossings with hysteresis at 4 noise sigmas of the measured series (noise near zero
    # would add crossings and raise the measured frequency)
    sigma = noise_level(m)
    band = 4.0 * sigma
    # Frequencies over the resolved swing only (a long decay's hours of noise would outweigh it)
    n_f = _resolved_end(t, m, sigma)
    t_f, m_f, c_f = t[:n_f], m[:n_f], c[:n_f]
    segs_f = segs if n_f == len(t) else segments(t_f, max_gap_s)
    g_m = spectral_peak_hz(*_uniform_grid(t_f, m_f, segs_f, dx))
    g_c = spectral_peak_hz(*_uniform_grid(t_f, c_f, segs_f, dx))
    # Crossings of the oscillation about its running mean over one period: a decaying swing moves
    # the mean of quantities like r omega^2 + g cos phi, so the global mean would miss crossings.
    period = round(1.0 / (g_m * dx)) if g_m > 0 else 0
    f_m = _frequency(_covered_zero_crossing_hz, t_f, m_f, band, segs_f, period, dx, uniform)
    f_c = _frequency(_covered_zero_crossing_hz, t_f, c_f, band, segs_f, period, dx, uniform)
    return Comparison(
        t_s=t if "t_s" in keep else empty,
        measured=_as_given(measured, m) if "measured" in keep else empty,
        computed=_as_given(computed, c) if "computed" in keep else empty,
        delta=delta if "delta" in keep else empty,
        iae=iae,
        ise=ise,
        iae_curve=iae_curve if "iae_curve" in keep else empty,
        ise_curve=ise_curve if "ise_curve" in keep else empty,
        rms=float(np.sqrt(sum_sq / len(t))),
        max_abs=max_abs,
        f_measured_hz=f_m,
        f_computed_hz=f_c,
        delta_f=abs(f_c - f_m) / f_m if f_m else float("nan"),
        f_measured_fft_hz=g_m,
        f_computed_fft_hz=g_c,
        delta_f_fft=abs(g_c - g_m) / g_m if g_m else float("nan"),
        covered_s=covered,
        measured_std=_std(m),
    )


def _as_given(given: np.ndarray, as_float: np.ndarray) -> np.ndarray:
    """A series to keep: the caller's float32 array as it is (half the memory of its float64
    copy), else its float64 version."""
    a = np.asarray(given)
    return a if a.dtype == np.float32 else as_float


def _std(x: np.ndarray) -> float:
    """Standard deviation of x (n,), window by window (no (n,) temporaries)."""
    mean = float(np.mean(x))
    total = sum(float(np.sum((x[a : a + WINDOW_SAMPLES] - mean) ** 2)) for a in range(0, len(x), WINDOW_SAMPLES))
    return float(np.sqrt(total / len(x)))
