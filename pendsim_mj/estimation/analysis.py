"""Signal analysis used by the CLI summary and the physics checks: frequencies and decay.

Imports no physics engine. All functions take uniformly sampled series: t_s (n,) in s.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np

from pendsim_mj.engines.linearised import linear_modes
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.checks import UNRESOLVED_SHARE, unresolved_balance
from pendsim_mj.rig.params import RigParams


def _check_series(t_s: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(x, dtype=float)
    if t.ndim != 1 or y.shape != t.shape:
        raise ParameterError(f"expected t_s and x of the same shape (n,), got {t.shape} and {y.shape}")
    if len(t) < 8:
        raise ParameterError(f"need at least 8 samples, got {len(t)}")
    return t, y


def checked_rows(t_s: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """t_s (n,) and rows x (m, n) as float arrays, checked: uniformly shaped, n >= 8.

    Raises:
      ParameterError: the shapes do not match, or fewer than 8 samples.
    """
    t = np.asarray(t_s, dtype=float)
    rows = np.asarray(x, dtype=float)
    if rows.ndim != 2 or rows.shape[1:] != t.shape:
        raise ParameterError(f"expected x of shape (m, {t.shape[0] if t.ndim == 1 else 'n'}), got {rows.shape}")
    _check_series(t, rows[0] if len(rows) else t)
    return t, rows


def noise_level(x: np.ndarray) -> float:
    """A robust estimate of the white-noise sigma of a smooth signal plus noise: the median
    absolute deviation of its second differences / sqrt(6) (the signal's own curvature adds to
    it, so this errs high for coarse sampling)."""
    y = np.asarray(x, dtype=float)
    if len(y) < 3:
        return 0.0
    d2 = np.empty(len(y) - 2)  # second differences block by block: one (n,) array, no first differences
    for lo in range(0, len(d2), _TURN_BLOCK):
        d2[lo : lo + _TURN_BLOCK] = np.diff(y[lo : lo + _TURN_BLOCK + 2], 2)
    # in place: one (n,) array (medians need no order, so they may reorder it)
    d2 -= np.median(d2, overwrite_input=True)
    return float(1.4826 * np.median(np.abs(d2, out=d2), overwrite_input=True) / np.sqrt(6.0))


def spectral_peak_hz(t_s: np.ndarray, x: np.ndarray, max_hz: float = np.inf, min_hz: float = 0.0) -> float:
    """Dominant frequency of x (Hz), below ``max_hz`` (and above ``min_hz``): the largest peak of
    its Hann-windowed spectrum, refined by a parabola through the log-magnitudes of the three bins
    around it (accuracy well below one bin, 1/duration). The mean is removed first; returns 0.0
    for a constant signal or when no bin lies between ``min_hz`` and ``max_hz``."""
    t, y = _check_series(t_s, x)
    return float(spectral_peak_hz_batch(t, y[None, :], max_hz, min_hz)[0])


def swing_frequency_hz(peak_hz: np.ndarray, duration_s: float, largest_abs_rad: np.ndarray) -> np.ndarray:
    """The dominant frequency where it is a swing's, NaN elsewhere (arrays of one shape, Hz and rad):
    below one cycle in the run the spectrum's largest peak is a decay's or a drift's (an overdamped
    hinge gave 4.6e-6 Hz), and a pendulum that went over the top (|phi| beyond pi at some instant)
    turned rather than swung: its angle's spectrum is the ramp of its turns, whose peak sits just
    above one cycle in the run (0.033-0.05 Hz on 30 s runs released near the top, a new user's sweep
    map coloured by them) whatever it did."""
    peak = np.asarray(peak_hz, dtype=float)
    swung = (peak * duration_s >= 1.0) & (np.asarray(largest_abs_rad) <= math.pi)
    return np.where(swung, peak, np.nan)


def padded_length(n: int) -> int:
    """FFT length for n samples: the power of two at or above 8 n (zero-padded 8x: a fine
    frequency grid to interpolate peaks on)."""
    return 1 << (8 * n - 1).bit_length()


def hann_magnitude(x: np.ndarray, nfft: int) -> np.ndarray:
    """|rfft| of each row of x (m, n) or of x (n,), mean removed and Hann-windowed, zero-padded
    to ``nfft``: (m, nfft // 2 + 1) or (nfft // 2 + 1,), units of x. The one windowed spectrum
    of this project (bin k is at k / (nfft dt) Hz)."""
    y = np.asarray(x, dtype=float)
    y = y - y.mean(axis=-1, keepdims=True)
    return np.abs(np.fft.rfft(y * np.hanning(y.shape[-1]), n=nfft, axis=-1))


# Rows transformed at once by spectral_peak_hz_batch: bounds its memory (rows x nfft/2 complex).
_SPECTRUM_BYTES = 64 * 2**20


def spectral_peak_hz_batch(t_s: np.ndarray, x: np.ndarray, max_hz: float = np.inf, min_hz: float = 0.0) -> np.ndarray:
    """``spectral_peak_hz`` of each row of x (m, n) sampled at t_s (n,): (m,) Hz, in blocks of rows
    of bounded memory. A row with a non-finite value gives NaN."""
    t, rows = checked_rows(t_s, x)
    n = len(t)
    dt = (t[-1] - t[0]) / (n - 1)
    nfft = padded_length(n)
    nbins = nfft // 2 + 1
    top = min(nbins, int(np.ceil(max_hz * nfft * dt))) if np.isfinite(max_hz) else nbins
    bottom = max(1, int(np.ceil(min_hz * nfft * dt))) if min_hz > 0 else 1
    out = np.zeros(len(rows))
    if top < bottom + 1:
        return out
    if 16 * nbins > _SPECTRUM_BYTES:  # one row's spectrum is too large to hold: each row in parts
        for i, row in enumerate(rows):
            out[i] = _peak_in_parts(row, nfft, bottom, top) / (nfft * dt)
        return out
    block = max(1, _SPECTRUM_BYTES // (16 * nbins))
    for lo in range(0, len(rows), block):
        y = rows[lo : lo + block]
        spectrum = hann_magnitude(y, nfft)
        k = np.argmax(spectrum[:, bottom:top], axis=1) + bottom
        inside = k < nbins - 1
        kk = np.where(inside, k, 1)
        a, b, c = (np.log(spectrum[np.arange(len(y)), kk + d] + 1e-300) for d in (-1, 0, 1))
        denom = a - 2 * b + c
        with np.errstate(divide="ignore", invalid="ignore"):
            shift = np.where(inside & (denom != 0), 0.5 * (a - c) / np.where(denom != 0, denom, 1.0), 0.0)
        freq = (k + shift) / (nfft * dt)
        freq[~np.any(y != y[:, :1], axis=1)] = 0.0  # a constant row (zero included) has no frequency
        freq[~np.all(np.isfinite(y), axis=1)] = np.nan
        out[lo : lo + block] = freq
    return out


def second_peak_ratio_batch(t_s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """How clearly each row's spectral peak dominates: the height of its second-highest peak over
    the highest's, (m,) in [0, 1] for rows of x (m, n) sampled at t_s (n,).

    Peaks are the local maxima of the windowed spectrum of ``spectral_peak_hz_batch``
    (``hann_magnitude``, 8x zero padding), each height refined by the parabola through the
    log-magnitudes of its bin and its two neighbours; the second is the highest peak outside the
    first's main lobe (the Hann window's: +-2 bins of 1 / duration; its side lobes are 31 dB down).
    0 for a single peak or a constant row, NaN for a row with a non-finite value. A row whose
    padded spectrum would exceed the memory bound is transformed with less padding (at least its
    own length, rounded up to a power of two)."""
    t, rows = checked_rows(t_s, x)
    n = len(t)
    nfft = padded_length(n)
    while 16 * (nfft // 2 + 1) > _SPECTRUM_BYTES and nfft >= 2 * n:
        nfft //= 2
    out = np.full(len(rows), np.nan)
    if 16 * (nfft // 2 + 1) > _SPECTRUM_BYTES:
        return out
    lobe = 2 * nfft / n  # the main lobe's half-width in padded bins
    block = max(1, _SPECTRUM_BYTES // (16 * (nfft // 2 + 1)))
    for lo in range(0, len(rows), block):
        y = rows[lo : lo + block]
        logs = np.log(hann_magnitude(y, nfft)[:, 1:] + 1e-300)  # without the zero-frequency bin
        a, b, c = logs[:, :-2], logs[:, 1:-1], logs[:, 2:]
        is_peak = (b > a) & (b >= c)
        denom = a - 2 * b + c
        with np.errstate(divide="ignore", invalid="ignore"):
            height = np.where(denom < 0, b - (a - c) ** 2 / (8 * denom), b)  # the parabola's vertex
        height = np.where(is_peak, height, -np.inf)
        first = np.argmax(height, axis=1)
        bins = np.arange(height.shape[1])
        outside = np.abs(bins[None, :] - first[:, None]) > lobe
        second = np.max(np.where(outside, height, -np.inf), axis=1)
        top = height[np.arange(len(y)), first]
        with np.errstate(invalid="ignore", over="ignore"):
            ratio = np.where(np.isfinite(second), np.exp(second - top), 0.0)
        ratio[~np.isfinite(top)] = 0.0
        ratio[~np.any(y != y[:, :1], axis=1)] = 0.0
        ratio[~np.all(np.isfinite(y), axis=1)] = np.nan
        out[lo : lo + block] = ratio
    return out


SPECTRUM_PARTS = 16
"""A long series' zero-padded spectrum is computed in this many interleaved parts (bins r, r + 16,
r + 32, ...; ``_peak_in_parts``): a sixteenth of its memory. Each part is the transform of length
nfft / SPECTRUM_PARTS of the windowed series turned by exp(-2 pi i r j / nfft) and folded onto
that length (sample j added at j mod the length: the part's bins are periodic in j with it)."""


def _dft_magnitude(w: np.ndarray, k: int, nfft: int) -> float:
    """|sum_j w_j exp(-2 pi i k j / nfft)|: one bin of the zero-padded transform (the phase taken
    from the exact integer k j mod nfft)."""
    total = 0j
    for lo in range(0, len(w), _TURN_BLOCK):
        j = np.arange(lo, min(lo + _TURN_BLOCK, len(w)), dtype=np.int64)
        total += complex(np.sum(w[j] * np.exp(-2j * np.pi * ((k * j) % nfft) / nfft)))
    return float(abs(total))


def _peak_in_parts(y: np.ndarray, nfft: int, bottom: int, top: int) -> float:
    """The peak bin of ``hann_magnitude(y, nfft)`` in [bottom, top), refined as in
    ``spectral_peak_hz_batch`` (in bins; NaN for a non-finite y, 0 for a constant one), without
    holding the whole spectrum: bins k = SPECTRUM_PARTS m + r are the transform of length
    nfft / SPECTRUM_PARTS of y's windowed samples turned by exp(-2 pi i r j / nfft) and folded
    onto that length, made in one reused buffer (transformed in place by numpy's FFT, which keeps
    no plan: scipy.fft would keep the part's plan for the rest of the process); the three bins
    around the peak are summed directly (``_dft_magnitude``), so only the peak's bin comes from
    the parts."""
    if not np.all(np.isfinite(y)):
        return float("nan")
    if not np.any(y != 0):
        return 0.0
    w = y - y.mean()
    w *= np.hanning(len(y))  # in place: no third (n,) array
    length = nfft // SPECTRUM_PARTS
    assert length % _TURN_BLOCK == 0, "parts are for long series: nfft / SPECTRUM_PARTS is a power of 2 >= 2^19"
    buffer = np.zeros(length, dtype=complex)
    turned = np.empty(_TURN_BLOCK, dtype=complex)
    offsets = np.arange(_TURN_BLOCK, dtype=np.int64)
    best, k = -1.0, bottom
    for r in range(SPECTRUM_PARTS):
        first = max(0, -(-(bottom - r) // SPECTRUM_PARTS))  # the part's bins m with bottom <= P m + r < top
        last = min(length, -(-(top - r) // SPECTRUM_PARTS))
        if last <= first:
            continue
        # w turned by exp(-2 pi i r j / nfft), block by block: the turn within a block (one table
        # per part) times the turn at the block's start (phases from exact integers r j mod nfft)
        within = np.exp(-2j * np.pi * ((r * offsets) % nfft) / nfft)
        for lo in range(0, len(w), _TURN_BLOCK):
            hi = min(lo + _TURN_BLOCK, len(w))
            block = turned[: hi - lo]
            np.multiply(within[: hi - lo], np.exp(-2j * np.pi * ((r * lo) % nfft) / nfft), out=block)
            block *= w[lo:hi]
            at = lo % length  # a block lies inside one period of the part (length: whole blocks)
            if lo < length:
                buffer[at : at + hi - lo] = block
            else:  # folded: sample j adds to bin-periodic position j mod length
                buffer[at : at + hi - lo] += block
        buffer[len(w) :] = 0.0
        spectrum = np.fft.fft(buffer, out=buffer) if _FFT_IN_PLACE else np.fft.fft(buffer)
        for lo in range(first, last, _TURN_BLOCK):  # the magnitudes block by block (no (length,) copy)
            magnitude = np.abs(spectrum[lo : min(lo + _TURN_BLOCK, last)])
            i = int(np.argmax(magnitude))
            if magnitude[i] > best:  # the first of equal peaks, as one argmax over the part
                best, k = float(magnitude[i]), SPECTRUM_PARTS * (lo + i) + r
        del spectrum
    if k >= nfft // 2:  # the last bin: no neighbour above it
        return float(k)
    a, b, c = (math.log(_dft_magnitude(w, kk, nfft) + 1e-300) for kk in (k - 1, k, k + 1))
    denom = a - 2 * b + c
    return k + (0.5 * (a - c) / denom if denom != 0 else 0.0)


_TURN_BLOCK = 1 << 16
_FFT_IN_PLACE = int(np.__version__.split(".")[0]) >= 2  # numpy.fft's ``out`` (numpy 2)


def _hysteresis_sign(y: np.ndarray, band: float) -> np.ndarray | None:
    """+1 / -1 per sample: the side of +-band the signal was last on (the first known side
    before that); None if it never leaves the band twice."""
    state = np.zeros(len(y), dtype=np.int8)  # one byte a sample (a long run: no int64 temporaries)
    state[y > band] = 1
    state[y < -band] = -1
    known = np.flatnonzero(state)
    if len(known) < 2:
        return None
    # each known side held up to the next one; before the first, the first
    filled = np.empty(len(y), dtype=np.int8)
    filled[: known[0]] = state[known[0]]
    filled[known[0] :] = np.repeat(state[known], np.diff(known, append=len(y)))
    return filled


def upward_crossings(t_s: np.ndarray, x: np.ndarray, hysteresis: float = 0.0) -> np.ndarray:
    """Instants (s) of the upward zero crossings of x - mean(x), linearly interpolated. With
    ``hysteresis`` h > 0 a crossing counts only once the signal has been below -h and then above
    +h, so noise near zero adds no crossings (each counted crossing is still interpolated where
    the signal passes zero). Works on any increasing instants (n,)."""
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(x, dtype=float)
    y = y - y.mean()
    if hysteresis > 0:
        filled = _hysteresis_sign(y, hysteresis)
        if filled is None:
            return np.zeros(0)
        rises = np.flatnonzero((filled[:-1] == -1) & (filled[1:] == 1)) + 1  # first sample above +h
        below = np.flatnonzero(y < 0)
        idx = below[np.searchsorted(below, rises, side="right") - 1]  # last sample below 0 before it
    else:
        idx = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    return t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])


def zero_crossing_hz(t_s: np.ndarray, x: np.ndarray, hysteresis: float = 0.0) -> float:
    """Mean frequency (Hz) from the upward zero crossings of x - mean(x) (``upward_crossings``),
    between the first and the last crossing. Raises ParameterError with fewer than 2."""
    t, y = _check_series(t_s, x)
    crossings = upward_crossings(t, y, hysteresis)
    if len(crossings) < 2:
        raise ParameterError("fewer than two upward zero crossings: the series is too short to give a frequency")
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


@dataclasses.dataclass(frozen=True)
class Beat:
    """The beat of a swing, measured on its carrier band (``beat``).

    Attributes:
      period_s: period of the envelope's modulation, s (inf when there is no beat: depth under
        ``MIN_BEAT_DEPTH`` or no modulation slower than the band's half-width).
      depth: modulation depth (high - low) / (high + low) of the carrier-band envelope, 0-1 (the
        damping decay divided out). Two sines of amplitudes a, b in the band: min(a, b) / max(a, b);
        an amplitude modulation (1 + m cos) of one sine: m.
      carrier_hz: the carrier, Hz (the dominant frequency, ``spectral_peak_hz``).
      band_hz: (low, high) edges of the carrier band, Hz.
    """

    period_s: float
    depth: float
    carrier_hz: float = 0.0
    band_hz: tuple[float, float] = (0.0, 0.0)


MIN_BEAT_DEPTH = 0.01  # shallower modulation is the ripple of a nonlinear swing, not a beat
CARRIER_BAND_FRACTION = 0.25  # the carrier band is carrier * (1 +- this), tapered beyond
CARRIER_TAPER_FRACTION = 0.15  # width of the band's cosine edges, as a fraction of the carrier


def carrier_band(carrier_hz: float, dt_s: float) -> tuple[float, float]:
    """(low, high) Hz of the band kept around a carrier: carrier * (1 -+ CARRIER_BAND_FRACTION),
    below Nyquist. Lines outside it (the other normal modes) mix with the carrier into a fast
    ripple of the envelope, which is not a beat."""
    nyquist = 0.5 / dt_s
    return carrier_hz * (1 - CARRIER_BAND_FRACTION), min(carrier_hz * (1 + CARRIER_BAND_FRACTION), 0.95 * nyquist)


def carrier_envelope(t_s: np.ndarray, x: np.ndarray, carrier_hz: float | None = None) -> np.ndarray:
    """(n,) envelope of x on its carrier band: the magnitude of the analytic signal of x - mean(x)
    restricted to that band. One FFT, as the Hilbert transform computes the analytic signal
    (scipy.signal.hilbert: positive frequencies doubled, the rest zeroed), with its mask narrowed
    to ``carrier_band`` and cosine-tapered over ``CARRIER_TAPER_FRACTION`` * carrier outside it
    (a short kernel in time: only the first and last few seconds see the record's ends). Uniform
    instants t_s (n,); the carrier defaults to the dominant frequency. Zeros when x has no
    carrier."""
    t, y = _check_series(t_s, x)
    dt = (t[-1] - t[0]) / (len(t) - 1)
    f0 = spectral_peak_hz(t, y) if carrier_hz is None else float(carrier_hz)
    if not f0 > 0:
        return np.zeros(len(y))
    low, high = carrier_band(f0, dt)
    taper = CARRIER_TAPER_FRACTION * f0
    n = len(y)
    nfft = 1 << (2 * n - 1).bit_length()  # zero padding: the record's end does not wrap onto its start
    freq = np.fft.fftfreq(nfft, dt)
    outside = np.maximum(low - freq, freq - high) / taper  # <= 0 inside the band, 1 at the taper's end
    mask = np.where(outside <= 0, 1.0, np.where(outside < 1, 0.5 * (1 + np.cos(np.pi * outside)), 0.0))
    mask[freq <= 0] = 0.0
    analytic = np.fft.ifft(np.fft.fft(y - y.mean(), nfft) * (2.0 * mask))[:n]
    return np.asarray(np.abs(analytic))


def beat(t_s: np.ndarray, x: np.ndarray, *, edge_s: float = 5.0, carrier_hz: float | None = None) -> Beat:
    """Period and depth of the beat of x, measured on its carrier band.

    The envelope is ``carrier_envelope`` (so other modes, outside the band, cannot pass for a
    beat); ``edge_s`` at both ends is ignored (filter and Hilbert edge effects); the damping decay
    is divided out (a straight line fitted to log envelope). The period is the spectral peak of
    that flattened envelope between two periods per ignored-edges span and the band's
    half-width; the depth is (high - low) / (high + low)
    of the 1st and 99th percentiles of the envelope about its running geometric mean over one beat
    period (exact for a periodic modulation of a decaying swing). ``carrier_hz`` chooses another
    carrier than the dominant frequency (e.g. the other pendulum's).
    """
    t_all, y = _check_series(t_s, x)
    dt = (t_all[-1] - t_all[0]) / (len(t_all) - 1)
    carrier_hz = spectral_peak_hz(t_all, y) if carrier_hz is None else float(carrier_hz)
    if not carrier_hz > 0:
        return Beat(math.inf, 0.0)
    band = carrier_band(carrier_hz, dt)
    env = carrier_envelope(t_all, y, carrier_hz)
    none = Beat(math.inf, 0.0, carrier_hz, band)
    inner = (t_all >= t_all[0] + edge_s) & (t_all <= t_all[-1] - edge_s)
    t, e = t_all[inner], env[inner]
    if len(t) < 16 or np.any(e <= 0):
        return none
    flat = e / np.exp(np.polyval(np.polyfit(t, np.log(e), 1), t))  # the damping decay divided out
    # at least two beat periods inside: slower drift of the envelope is not a beat
    f = spectral_peak_hz(t, flat, max_hz=carrier_hz * CARRIER_BAND_FRACTION, min_hz=2.0 / (t[-1] - t[0]))
    if not f > 0:
        return none
    window = round(1.0 / (f * dt))
    if not 2 < window < len(e) // 2:
        return none
    log_e = np.log(e)
    trend = np.convolve(log_e, np.ones(window) / window, mode="valid")
    ratio = np.exp(log_e[window // 2 : window // 2 + len(trend)] - trend)
    low, high = np.percentile(ratio, [1, 99])
    depth = float((high - low) / (high + low))
    if depth < MIN_BEAT_DEPTH:
        return Beat(math.inf, depth, carrier_hz, band)
    return Beat(1.0 / f, depth, carrier_hz, band)


@dataclasses.dataclass(frozen=True)
class RunSummary:
    """What ``pendsim simulate`` prints about a run (single trajectory).

    Attributes:
      dominant_hz: (2,) spectral peak of phi1, phi2, Hz.
      start_amplitude_rad, end_amplitude_rad: (2,) first and last half-cycle amplitude of each
        angle (|phi| at the start or end where no half-cycle peak exists), rad.
      largest_rad: (2,) largest |phi| over the run, rad (beyond pi: the pendulum went over the top).
      energy_start_j, energy_end_j: total energy above rest at the first and last instant, J.
      dissipated_j: energy dissipated by the hinges (damping and dry friction) over the run, J.
      input_work_j: work done on the pendulums by the drive over the run (``input_work_j``), J.
      energy_scale_j: m1 g OC1, J (what ``unresolved`` compares the balance with).
      driven: the run had a drive (its balance is not checked: the drive's work is integrated by
        the trapezoid rule, second order).
      fastest_mode_hz: the rig's fastest normal mode at rest, Hz (``linearised.linear_modes``).
    """

    duration_s: float
    dt_s: float
    samples: int
    dominant_hz: tuple[float, float]
    start_amplitude_rad: tuple[float, float]
    end_amplitude_rad: tuple[float, float]
    energy_start_j: float
    energy_end_j: float
    dissipated_j: float
    input_work_j: float = 0.0
    energy_scale_j: float = math.nan
    driven: bool = False
    fastest_mode_hz: float = math.nan
    largest_rad: tuple[float, float] = (0.0, 0.0)

    def swing_hz(self, k: int) -> float:
        """Pendulum k's (0, 1) swing frequency: ``dominant_hz`` where it is a swing's, else NaN
        (``swing_frequency_hz``)."""
        return float(swing_frequency_hz(np.array(self.dominant_hz[k]), self.duration_s, np.array(self.largest_rad[k])))

    @property
    def energy_lost_j(self) -> float:
        return self.energy_start_j - self.energy_end_j

    @property
    def unresolved(self) -> bool:
        """The step does not resolve this undriven run: its energy balance is off by more than
        ``checks.UNRESOLVED_SHARE`` of m1 g OC1 (as a sweep's ``unresolved`` column)."""
        return not self.driven and bool(unresolved_balance(self.balance_residual_j, self.energy_scale_j))

    def unresolved_warning(self) -> str | None:
        """What to tell the user about an ``unresolved`` run (None: resolved or not checked):
        ``unresolved_warning``."""
        if self.driven:
            return None
        return unresolved_warning(self.balance_residual_j, self.energy_scale_j, self.dt_s, self.fastest_mode_hz)

    @property
    def balance_residual_j(self) -> float:
        """Energy lost plus the drive's work minus energy dissipated: the integration error."""
        return self.energy_lost_j + self.input_work_j - self.dissipated_j


def summarize(traj: Trajectory) -> RunSummary:
    """Frequencies, amplitudes and the energy balance of a single run."""
    freqs, starts, ends = [], [], []
    for k in range(2):
        x = traj.phi_rad[:, k]
        freqs.append(spectral_peak_hz(traj.t_s, x))
        _, amps = peak_amplitudes(traj.t_s, x)
        starts.append(float(amps[0]) if len(amps) else abs(float(x[0])))
        ends.append(float(amps[-1]) if len(amps) else abs(float(x[-1])))
    energy = traj.total_energy_j
    params = traj.params if isinstance(traj.params, RigParams) else traj.params[0]
    return RunSummary(
        duration_s=float(traj.t_s[-1]),
        dt_s=traj.dt_s,
        samples=len(traj.t_s),
        dominant_hz=(freqs[0], freqs[1]),
        start_amplitude_rad=(starts[0], starts[1]),
        end_amplitude_rad=(ends[0], ends[1]),
        energy_start_j=float(energy[0]),
        energy_end_j=float(energy[-1]),
        dissipated_j=float(traj.dissipated_j[-1]),
        input_work_j=float(input_work_j(traj)[-1]),
        energy_scale_j=params.m1_kg * params.g_m_s2 * params.oc1_m,
        driven=bool(np.any(traj.drive_input)),
        fastest_mode_hz=float(np.max(linear_modes(params).frequency_hz)),
        largest_rad=(float(np.max(np.abs(traj.phi_rad[:, 0]))), float(np.max(np.abs(traj.phi_rad[:, 1])))),
    )


def unresolved_warning(
    residual_j: float, energy_scale_j: float, dt_s: float, fastest_mode_hz: float, *, remedy: str | None = None
) -> str | None:
    """What to tell the user about a run whose energy balance is off by ``residual_j`` (J) at the
    step ``dt_s`` (s), None where it is within ``checks.UNRESOLVED_SHARE`` of ``energy_scale_j``
    (m1 g OC1, J): the balance's error, the fastest mode's steps per period (``fastest_mode_hz``,
    the rig at rest; NaN: not said) and ``remedy``, by default a step to try (``finer_step_s``)."""
    if not unresolved_balance(residual_j, energy_scale_j):
        return None
    known = math.isfinite(fastest_mode_hz) and fastest_mode_hz > 0  # NaN: not known (the spatial model's tilts)
    per_period = 1.0 / (fastest_mode_hz * dt_s) if known else math.nan
    mode = f"; the fastest mode, {fastest_mode_hz:.3g} Hz at rest, gets {per_period:.3g} steps a period"
    if remedy is None:
        remedy = (
            f"run it again with --dt-s {finer_step_s(residual_j, energy_scale_j, dt_s, fastest_mode_hz):g} and compare"
        )
    share = abs(residual_j) / energy_scale_j
    return (
        f"dt_s = {dt_s:g} s does not resolve this run: its energy balance is off by {residual_j:.3g} J, {share:.2g} "
        f"times m1 g OC1 (the limit {UNRESOLVED_SHARE:g}{mode if known else ''}): its numbers are not to be trusted; "
        f"{remedy}"
    )


def finer_step_s(residual_j: float, energy_scale_j: float, dt_s: float, fastest_mode_hz: float) -> float:
    """A step (s, 1, 2 or 5 times a power of ten) to try after a balance off by ``residual_j`` at
    ``dt_s``: RK4 takes energy from a mode at a rate that goes as h^5, so the step that brings the
    error to a third of the limit is dt_s (limit / 3 / |residual|)^(1/5); where the run lost most
    of its energy that law no longer holds, and the step is also at most 1/50 of the fastest mode's
    period (``fastest_mode_hz``, NaN: not known) and a fifth of dt_s."""
    limit = UNRESOLVED_SHARE * energy_scale_j
    scaled = dt_s * (limit / 3.0 / max(abs(residual_j), limit)) ** 0.2
    known = math.isfinite(fastest_mode_hz) and fastest_mode_hz > 0
    return _one_two_five_below(min(scaled, dt_s / 5, 1.0 / (50 * fastest_mode_hz) if known else math.inf))


class BlockBalance:
    """A run's energy balance gathered block by block (``engines.run_blocks``: memory flat): the
    energy at its first and last row and what its losses took (``Trajectory.dissipated_j``,
    cumulative over the blocks); ``warning`` as ``unresolved_warning`` for an undriven run (a
    drive's work is not counted here)."""

    def __init__(self) -> None:
        self.start_j = self.end_j = self.dissipated_j = math.nan
        self.driven = False

    def add(self, traj: Trajectory, first: int) -> None:
        """A block of a single run whose first row is the run's row ``first``."""
        energy = traj.total_energy_j
        if first == 0:
            self.start_j = float(energy[0])
        self.end_j, self.dissipated_j = float(energy[-1]), float(traj.dissipated_j[-1])
        self.driven = self.driven or bool(np.any(traj.drive_input))

    @property
    def residual_j(self) -> float:
        return self.start_j - self.end_j - self.dissipated_j

    def warning(self, params: RigParams, dt_s: float, *, planar: bool = True, remedy: str | None = None) -> str | None:
        """``unresolved_warning`` of the run so far (None: resolved, driven or empty); ``planar``
        False: the spatial model (its fastest mode, a tilt's perhaps, is not said)."""
        if self.driven or math.isnan(self.start_j):
            return None
        fastest = float(np.max(linear_modes(params).frequency_hz)) if planar else math.nan
        scale = params.m1_kg * params.g_m_s2 * params.oc1_m
        return unresolved_warning(self.residual_j, scale, dt_s, fastest, remedy=remedy)


def _one_two_five_below(value: float) -> float:
    """The largest of 1, 2, 5 times a power of ten that is at most ``value`` (> 0)."""
    decade = 10.0 ** math.floor(math.log10(value))
    return max(m * decade for m in (1.0, 2.0, 5.0) if m * decade <= value * (1 + 1e-12))


def input_work_j(traj: Trajectory) -> np.ndarray:
    """(n,) work done on the pendulums by the drive since t = 0, J (zeros without a drive).

    In the support's frame the power is sum_n tau_n omega_n - m_n OC_n omega_n (a_v sin phi_n +
    a_h cos phi_n) (torques, and the inertial force of the support's acceleration at each centre
    of mass; see ``pendsim_mj.engines.reference``). Each step's power is integrated with the
    trapezoid rule over the states at both ends of the step, with the input at each end (the
    trajectory's ``drive_sampling`` "stages": the signal there) or the input held over the step
    ("held", MuJoCo): second order in dt (the planar rig; the spatial variant's tilt is not
    counted).
    """
    if traj.drive is None:
        return np.zeros(len(traj.t_s))
    p = traj.single_params
    u_start = traj.drive_input[:-1]
    u_end = traj.drive_input[1:] if traj.drive_sampling == "stages" else u_start
    moc = np.array([p.m1_kg * p.oc1_m, p.m2_kg * p.oc2_m])

    def power(w: np.ndarray, phi: np.ndarray, u: np.ndarray) -> np.ndarray:
        support = u[:, 3:4] * np.sin(phi) + u[:, 2:3] * np.cos(phi)
        return np.asarray(np.sum(u[:, :2] * w - moc * w * support, axis=1))

    w, phi = traj.omega_rad_s, traj.phi_rad
    step = 0.5 * traj.dt_s * (power(w[:-1], phi[:-1], u_start) + power(w[1:], phi[1:], u_end))
    return np.concatenate([[0.0], np.cumsum(step)])
