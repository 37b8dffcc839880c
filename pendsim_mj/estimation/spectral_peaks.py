"""The spectral peak and its clarity for many rows at once, at the cost of a short transform: the
values of ``analysis.spectral_peak_hz_batch`` and ``analysis.second_peak_ratio_batch`` (Hann
window, 8x zero padding, log-parabola refinement), computed the way a sweep of 10^5-10^6 runs can
afford.

Why it gives the same numbers: zero padding only interpolates. The padded spectrum S(k) (nfft =
``analysis.padded_length(n)`` points, 8 n or more) is sampled exactly at every ``COARSE_FACTOR``-th
bin by the transform of length nfft / COARSE_FACTOR (still at least 2 n: S_c(j) = S(P j), P =
COARSE_FACTOR). A peak of S lies between the coarse samples around a local maximum of S_c, and
the coarse sample nearest it is at most P / 2 fine bins away, where a Hann main lobe has lost at
most 4 % of its height (coarse bins are at most half the window's bin 1 / (n dt): W(1/4) = 0.960).
So every local maximum of S_c within ``CANDIDATE_SHARE`` of the highest is a candidate, and
around each the fine bins within P / 2 + 1 of it (P + 3 bins: the peak and its two neighbours) are evaluated
exactly by Goertzel's recurrence, O(n) each, in rounds: the highest coarse bins first, then any
left within ``CANDIDATE_SHARE`` of the best peak found (a peak on the shoulder of a higher one is
no coarse local maximum of its own, but its coarse samples are high). The
highest fine bin, its neighbours and the parabola through their log-magnitudes are then those of
the padded transform, up to rounding (about 1e-12 relative).

The second peak (``second_peak_ratio_batch``: the highest peak outside the first's main lobe,
+-2 bins of 1 / duration) is refined the same way among the coarse local maxima outside that lobe.
A small side lobe (a pure tone's first, 31 dB down) can fall between coarse samples and be missed
or lowered: ratios below ``RATIO_EXACT_FROM`` may differ from the padded transform's (by less
than that value: both are small); at and above it they are the same (they come from separate
spectral components, several bins wide). The ambiguity flag (ratio >= 0.8) is the same.

A second peak below ``RATIO_EXACT_FROM`` of the first is not refined at all (coarse bins below
that share of it, less the 4 %, are not candidates), which spares walking down the first peak's
flank round by round; its ratio is then the highest coarse local maximum outside the first's
lobe over the first's height (a pure tone's side lobe: 0.02-0.03, where the padded transform
gives 0.027), not a zero that would read as "no second peak".

Measured against the padded transform on 1000 sweep cases (``tests/sweep/test_sweep_light.py``):
frequencies equal to 1e-9 Hz, ratios >= RATIO_EXACT_FROM to 1e-9. Cost: one single-precision
transform of length nfft / 4 per row (its magnitudes only choose the candidates) and about 45
Goertzel bins (n = 3001, 200 sweep rows; 86 before the narrower windows and the floor), several
times less than the two padded transforms it replaces (``bench/bench_sweep_scale.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import scipy.fft
from numpy.typing import NDArray

from pendsim_mj import compile_notice
from pendsim_mj.estimation.analysis import checked_rows, padded_length

compile_notice.watch()

FloatArray = NDArray[np.float64]
COARSE_FACTOR = 4  # fine (padded) bins per coarse bin
CANDIDATE_SHARE = 0.85  # coarse local maxima at least this share of the highest are refined
MAX_ROUNDS = 8  # refinement rounds per search at most (each lowers the bar by CANDIDATE_SHARE)
RATIO_EXACT_FROM = 0.1  # second-peak ratios from here up equal the padded transform's
_TINY = 1e-300  # added before the log, as analysis does
_BLOCK_BYTES = 64 * 2**20  # bound on one block's coarse spectra


@numba.njit(cache=True, fastmath={"contract"})
def _goertzel(y: FloatArray, bins: NDArray[np.int64], nfft: int) -> FloatArray:
    """log(|sum_j y_j exp(-2 pi i k j / nfft)| + tiny) for each fine bin k of ``bins``: Goertzel's
    recurrence, eight bins at a time over the samples (eight independent chains in registers: the
    recurrence is bound by its latency, 0.48 ns per bin and sample against 0.83 for one chain at
    a time). Each step is written (x - s[j - 2]) + c s[j - 1] and may be contracted into one fused
    multiply-add (the only fast-math licence taken): two operations per chain instead of three,
    1.2-1.7x faster (8 to 24 bins of 3001 samples; values within 1e-13 of the unfused)."""
    count = len(bins)
    out = np.empty(count)
    c = np.zeros(8)
    s1 = np.zeros(8)
    s2 = np.zeros(8)
    for g in range(0, count, 8):
        c[:] = 0.0
        for b in range(min(8, count - g)):
            c[b] = 2.0 * math.cos(2.0 * math.pi * bins[g + b] / nfft)
        c0, c1, c2, c3, c4, c5, c6, c7 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = 0.0  # s[j - 1] per bin
        b0 = b1 = b2 = b3 = b4 = b5 = b6 = b7 = 0.0  # s[j - 2]
        for j in range(len(y)):
            v = y[j]
            a0, b0 = (v - b0) + c0 * a0, a0
            a1, b1 = (v - b1) + c1 * a1, a1
            a2, b2 = (v - b2) + c2 * a2, a2
            a3, b3 = (v - b3) + c3 * a3, a3
            a4, b4 = (v - b4) + c4 * a4, a4
            a5, b5 = (v - b5) + c5 * a5, a5
            a6, b6 = (v - b6) + c6 * a6, a6
            a7, b7 = (v - b7) + c7 * a7, a7
        s1[0], s1[1], s1[2], s1[3], s1[4], s1[5], s1[6], s1[7] = a0, a1, a2, a3, a4, a5, a6, a7
        s2[0], s2[1], s2[2], s2[3], s2[4], s2[5], s2[6], s2[7] = b0, b1, b2, b3, b4, b5, b6, b7
        for b in range(min(8, count - g)):
            power = s1[b] * s1[b] + s2[b] * s2[b] - c[b] * s1[b] * s2[b]
            out[g + b] = math.log(math.sqrt(max(0.0, power)) + _TINY)
    return out


_FINITE, _NOT_FINITE, _CONSTANT = 0, 1, 2  # what ``_windowed`` says of a row


@numba.njit(parallel=True, cache=True)
def _windowed(
    rows: FloatArray, window: FloatArray, out: FloatArray, out32: NDArray[np.float32], kind: NDArray[np.int8]
) -> None:
    """(row - its mean) * window for every row (m, n), into out and, rounded, out32 (the coarse
    transform's input: its magnitudes only choose candidates; (m, N >= n), its columns from n on
    zeroed: the transform's padding, so it takes out32 as it is); a row with a non-finite value
    as zeros (its results are NaN anyway). kind (m,): ``_NOT_FINITE``, ``_CONSTANT`` (every value
    equal, zero included) or ``_FINITE``."""
    n = rows.shape[1]
    for r in numba.prange(rows.shape[0]):
        total = 0.0
        finite = True
        constant = True
        first = rows[r, 0]
        for j in range(n):
            total += rows[r, j]
            finite = finite and math.isfinite(rows[r, j])
            constant = constant and rows[r, j] == first
        mean = total / n
        for j in range(n):
            v = (rows[r, j] - mean) * window[j] if finite else 0.0
            out[r, j] = v
            out32[r, j] = v
        out32[r, n:] = 0.0
        kind[r] = _NOT_FINITE if not finite else (_CONSTANT if constant else _FINITE)


@numba.njit(parallel=True, cache=True)
def _magnitudes(z: NDArray[np.complex64]) -> FloatArray:
    """|z| as float64, (m, k), in one pass (numpy's abs then astype took two, and a copy)."""
    out = np.empty(z.shape)
    for r in numba.prange(z.shape[0]):
        for j in range(z.shape[1]):
            v = z[r, j]
            out[r, j] = math.sqrt(float(v.real) * float(v.real) + float(v.imag) * float(v.imag))
    return out


@numba.njit(cache=True)
def _windows(centres: NDArray[np.int64], count: int, p: int, nbins: int) -> NDArray[np.int64]:
    """The fine bins from P j - P / 2 - 1 to P j + P / 2 + 1 around every coarse centre j of
    centres[:count] (ascending): a peak whose nearest coarse sample is j, and its two neighbours;
    within 0 .. nbins - 1, ascending and each once."""
    reach = p // 2 + 1
    out = np.empty(count * (2 * reach + 1), dtype=np.int64)
    size = 0
    for q in range(count):
        lo = max(0, p * centres[q] - reach, out[size - 1] + 1 if size else 0)
        for k in range(lo, min(nbins, p * centres[q] + reach + 1)):
            out[size] = k
            size += 1
    return out[:size]


@numba.njit(cache=True)
def _vertex(a: float, v: float, e: float) -> float:
    """The height of the parabola through three log-magnitudes, at its vertex (analysis's rule)."""
    den = a - 2.0 * v + e
    return v - (a - e) ** 2 / (8.0 * den) if den < 0 else v


@numba.njit(cache=True)
def _highest_peak(
    y: FloatArray,
    c: FloatArray,
    eligible: NDArray[np.bool_],
    is_peak: NDArray[np.bool_],
    share: float,
    p: int,
    nfft: int,
    away_from: int,
    away_by: float,
    top: FloatArray,
    bounded: bool,
) -> tuple[int, float]:
    """The fine local maximum of bins 2 .. nbins - 2 farther than ``away_by`` from bin
    ``away_from`` with the highest parabola vertex (its bin, its log height; -1, -inf if none):
    refining the eligible coarse bins highest first, in rounds, until every coarse bin left is
    below ``share`` of the best found (at most MAX_ROUNDS rounds). Also keeps in ``top`` the highest
    bin of 1 .. nbins - 1 evaluated and the log-magnitudes around it: (bin, log S(k - 1), log S(k),
    log S(k + 1)), the neighbours NaN where not evaluated; the first round holds the coarse bins
    within ``share`` of the highest eligible one, so over every bin this is the argmax.
    ``bounded``: the eligible bins are few (above a floor): a round that found no peak is followed
    by one over all of them at once, instead of walking down a main lobe's flank round by round."""
    nbins = nfft // 2 + 1
    nc = len(c)
    done = np.zeros(nc, dtype=np.bool_)
    centres = np.empty(nc, dtype=np.int64)
    best_k, best_h = -1, -np.inf
    for round_ in range(MAX_ROUNDS):
        # this round's centres, in one pass over the coarse bins (each refined once): those
        # within share of the best peak found; with none found yet, every one left of a bounded
        # set after its first round, else those within share of the highest left and the local
        # maxima within share of the highest local maximum left (a peak beside a higher slope:
        # a drift at the lowest bins)
        bar, bar_peak = math.inf, math.inf
        if best_k >= 0:
            bar = share * math.exp(best_h)
        elif bounded and round_ > 0:
            bar = -math.inf
        else:
            top_left, top_peak = 0.0, 0.0
            for j in range(nc):
                if eligible[j] and not done[j]:
                    top_left = max(top_left, c[j])
                    if is_peak[j]:
                        top_peak = max(top_peak, c[j])
            bar, bar_peak = share * top_left, share * top_peak
        count = 0
        for j in range(nc):
            if eligible[j] and not done[j] and (c[j] >= bar or (is_peak[j] and c[j] >= bar_peak)):
                done[j] = True
                centres[count] = j
                count += 1
        if count == 0:
            break
        bins = _windows(centres, count, p, nbins)
        logs = _goertzel(y, bins, nfft)
        for b in range(len(bins)):
            if bins[b] >= 1 and (logs[b] > top[2] or top[0] < 0):
                top[0], top[2] = bins[b], logs[b]
                top[1] = logs[b - 1] if b > 0 and bins[b - 1] == bins[b] - 1 else np.nan
                top[3] = logs[b + 1] if b < len(bins) - 1 and bins[b + 1] == bins[b] + 1 else np.nan
        for b in range(1, len(bins) - 1):
            k = bins[b]
            inside = 2 <= k <= nbins - 2 and abs(k - away_from) > away_by
            if inside and bins[b - 1] == k - 1 and bins[b + 1] == k + 1 and logs[b - 1] < logs[b] >= logs[b + 1]:
                h = _vertex(logs[b - 1], logs[b], logs[b + 1])
                if h > best_h or (h == best_h and k < best_k):
                    best_k, best_h = k, h
    return best_k, best_h


@numba.njit(parallel=True, cache=True)
def _refine_kernel(
    rows: FloatArray,
    coarse: FloatArray,
    p: int,
    nfft: int,
    lobe: float,
    share: float,
    peak: FloatArray,
    ratio: FloatArray,
) -> None:
    """Per row of windowed rows (m, n) with coarse magnitudes (m, nfft / p / 2 + 1): the padded
    transform's peak bin plus the parabola's shift into peak (m,), and the second peak ratio."""
    nbins = nfft // 2 + 1
    for r in numba.prange(rows.shape[0]):
        y = rows[r]
        c = coarse[r]
        nc = len(c)
        is_peak = np.zeros(nc, dtype=np.bool_)
        for j in range(1, nc - 1):  # the edges (a drift's lowest bins) are no peak of their own
            is_peak[j] = c[j] >= c[j - 1] and c[j] >= c[j + 1]
        everywhere = np.ones(nc, dtype=np.bool_)
        # the highest peak (its vertex), and on the way the highest fine bin (argmax) with its neighbours
        top = np.array([-1.0, np.nan, -np.inf, np.nan])
        first_k, first_h = _highest_peak(y, c, everywhere, is_peak, share, p, nfft, -1, -1.0, top, False)
        best_k = int(top[0])
        shift = 0.0
        if 1 <= best_k < nbins - 1:
            a, v, e = top[1], top[2], top[3]
            if not (np.isfinite(a) and np.isfinite(e)):
                three = _goertzel(y, np.arange(best_k - 1, best_k + 2), nfft)
                a, v, e = three[0], three[1], three[2]
            den = a - 2.0 * v + e
            if den != 0:
                shift = 0.5 * (a - e) / den
        peak[r] = best_k + shift
        if first_k < 0:
            ratio[r] = 0.0
            continue
        # a second peak of ratio >= RATIO_EXACT_FROM has a coarse sample within 4 % of its height,
        # so coarse bins below the floor (share of that ratio) need no refining: a ratio below
        # RATIO_EXACT_FROM is only promised to stay below it
        floor = share * RATIO_EXACT_FROM * math.exp(first_h)
        outside = np.zeros(nc, dtype=np.bool_)
        low_peak = 0.0  # the highest coarse local maximum outside the lobe below the floor
        for j in range(nc):
            away = abs(p * j - first_k) > lobe - p
            outside[j] = away and c[j] >= floor
            if away and is_peak[j] and c[j] < floor:
                low_peak = max(low_peak, c[j])
        second_k, second_h = _highest_peak(
            y, c, outside, is_peak, share, p, nfft, first_k, lobe, np.full(4, np.nan), True
        )
        if second_k >= 0:
            ratio[r] = math.exp(second_h - first_h)
        else:  # below RATIO_EXACT_FROM: the coarse samples' estimate (a side lobe's, not a zero)
            ratio[r] = min(low_peak / math.exp(first_h), share * RATIO_EXACT_FROM)


def peaks_and_ratios(t_s: np.ndarray, x: np.ndarray, *, nthread: int | None = None) -> tuple[FloatArray, FloatArray]:
    """``spectral_peak_hz_batch(t_s, x)`` and ``second_peak_ratio_batch(t_s, x)`` of every row of
    x (m, n) sampled at t_s (n,), by the method of the module docstring: ((m,) Hz, (m,) ratio).

    A row with a non-finite value gives NaN for both; a constant row (zero included) frequency 0 and
    ratio 0 (as analysis)."""
    t, rows = checked_rows(t_s, x)
    n = len(t)
    dt = (t[-1] - t[0]) / (n - 1)
    nfft = padded_length(n)
    nfft_c = nfft // COARSE_FACTOR
    lobe = 2.0 * nfft / n
    window = np.hanning(n)
    freq = np.full(len(rows), np.nan)
    ratio = np.full(len(rows), np.nan)
    block = max(1, _BLOCK_BYTES // (16 * (nfft_c // 2 + 1) + 8 * n))
    workers = nthread or -1
    for lo in range(0, len(rows), block):
        raw = np.ascontiguousarray(rows[lo : lo + block])
        y = np.empty(raw.shape)
        y32 = np.empty((len(raw), nfft_c), dtype=np.float32)
        kind = np.empty(len(raw), dtype=np.int8)
        _windowed(raw, window, y, y32, kind)
        coarse = _magnitudes(scipy.fft.rfft(y32, axis=1, workers=workers))
        peak = np.empty(len(y))
        share = np.empty(len(y))
        _refine_kernel(y, coarse, COARSE_FACTOR, nfft, lobe, CANDIDATE_SHARE, peak, share)
        f = peak / (nfft * dt)
        f[kind == _CONSTANT] = 0.0  # a constant row (zero included) has no frequency
        share[kind == _CONSTANT] = 0.0
        f[kind == _NOT_FINITE] = np.nan
        share[kind == _NOT_FINITE] = np.nan
        freq[lo : lo + block] = f
        ratio[lo : lo + block] = share
    return freq, ratio
