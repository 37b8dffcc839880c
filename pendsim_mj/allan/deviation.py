"""Allan deviation of static IMU records, with confidence intervals and noise terms (IEEE 952).

- **Deviations**: the overlapping Allan deviation of each axis (frequency-type data: rates and
  accelerations) on a log-spaced tau grid, 12 values per decade from 1/fs to a tenth of the
  record. Computed exactly here rather than with ``allantools.oadev``: on this project's 2-core
  machine that took 1.7 s per axis for a 6 h, 80 Hz record on a 90-tau grid (20 s for 12 axes,
  against the 10 s budget for the whole analysis); this kernel (compiled by numba) sums the second
  differences of the phase (the running sum of the data less its mean, built once from the
  recording's own arrays: no joined copy) row by row over all axes, the taus spread over threads
  (one process, no workers), and equals ``allantools.oadev`` to 1e-11 (tests/allan/test_allan.py).
- **Confidence intervals**: the equivalent degrees of freedom of the overlapping estimator by
  Greenhall's algorithm (``edf_overlapping``; C. A. Greenhall and W. J. Riley, "Uncertainty of
  stability variances based on finite differences", PTTI 2003 / Greenhall 2004), and chi-squared
  intervals (NIST SP1065 eq. 45), with the noise type of each tau identified from the local
  log-log slope (-1/2 white, 0 flicker, +1/2 random walk). Both equal ``allantools.edf_greenhall``
  and ``allantools.confidence_interval`` bit for bit (tests/allan/test_allan.py), without importing
  allantools and scipy.stats (1.3 s of CPU at start-up, for two small functions): the intervals
  need only ``scipy.special.gammaincinv``.
- **Noise terms** fitted to the curve (IEEE 952 annex C): sigma^2(tau) = 3 Q^2 / tau^2 + N^2 / tau
  + 0.664^2 B^2 + K^2 tau / 3 + R^2 tau^2 / 2 with non-negative coefficients, each point weighted
  by its estimate's spread: white noise N (velocity or angle random walk), bias instability B
  (0.664 = sqrt(2 ln 2 / pi)), rate random walk K; Q and R so that they do not pass for N or K. A
  term the record does not resolve (not significant, or nowhere dominant) is None
  (``noise_terms``).
- **Sampling**: Allan deviation assumes uniform sampling; ``check_sampling`` finds gaps and
  irregular timestamps so that they are reported, not silently analysed.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors.bno055 import MIN_MOTION_RAD_S
from pendsim_mj.units import NS_PER_S, seconds

TAUS_PER_DECADE = 12
ONE_SIGMA = math.erf(1 / math.sqrt(2))  # 0.6827: 1-sigma confidence
BIAS_INSTABILITY_FACTOR = math.sqrt(2 * math.log(2) / math.pi)  # 0.664


def tau_grid(n_samples: int, per_decade: int = TAUS_PER_DECADE) -> np.ndarray:
    """Averaging factors m (integers, tau = m / fs) from 1 to n_samples / 10, log-spaced."""
    top = n_samples / 10
    if top < 2:
        raise ParameterError(f"need at least 20 samples for an Allan deviation, got {n_samples}")
    count = int(math.log10(top) * per_decade) + 1
    return np.unique(np.rint(np.logspace(0, math.log10(top), count)).astype(np.int64))


def phase(*columns: np.ndarray) -> np.ndarray:
    """The phase x (n+1, a) of frequency-type data given as column blocks (each (n,) or (n, k),
    together a columns; float32 data is summed in float64): x[0] = 0, x[i] = sum of the first
    i samples less the column's mean. Built straight from the blocks in one compiled pass
    (``allan_kernel.running_sum_into``: no copy of the data). The mean only adds a straight line
    to x, which the second differences cancel; without it, x grows to n * mean and the sums lose
    digits."""
    from pendsim_mj.allan import kernel as allan_kernel  # numba only once needed

    blocks = [np.asarray(c).reshape(len(c), -1) for c in columns]
    n = len(blocks[0])
    x = np.empty((n + 1, sum(b.shape[1] for b in blocks)))
    x[0] = 0.0
    j = 0
    for b in blocks:
        if len(b) != n:
            raise ParameterError(f"column blocks must be equally long, got {n} and {len(b)}")
        if b.dtype not in (np.float32, np.float64):
            b = b.astype(float)
        allan_kernel.running_sum_into(x, j, b, b.mean(axis=0, dtype=np.float64))
        j += b.shape[1]
    return x


def overlapping_adev(y: np.ndarray, m: np.ndarray, *, threads: int = 2) -> np.ndarray:
    """Overlapping Allan deviation of frequency-type data.

    Args:
      y: (n,) or (n, a) samples (a axes), uniformly sampled.
      m: averaging factors (tau = m / fs), each <= (n - 1) / 2.
      threads: 1: this thread only; more: the taus spread over numba's threads (one process,
        the data not copied; the same results bit for bit).

    Returns:
      (len(m),) or (len(m), a) deviations in the units of y.
    """
    y = np.asarray(y, dtype=float)
    flat = y.ndim == 1
    out = adev_of_phase(phase(y), m, threads=threads)
    return out[:, 0] if flat else out


def adev_of_phase(x: np.ndarray, m: np.ndarray, *, threads: int = 2) -> np.ndarray:
    """Overlapping Allan deviation (len(m), a) from the phase x (n+1, a) (``phase``)."""
    m = np.asarray(m, dtype=np.int64)
    n = len(x) - 1
    if np.any(m < 1) or np.any(2 * m > n):
        raise ParameterError(f"averaging factors must be in 1..{n // 2}, got {m.min()}..{m.max()}")
    from pendsim_mj.allan import kernel as allan_kernel  # numba (and its compiled kernels) only once needed

    x = np.ascontiguousarray(x, dtype=float)
    if threads <= 1 or x.size <= 2_000_000 or len(m) < 2:
        return np.asarray(allan_kernel.oadev_serial(x, m))
    # the taus dealt round-robin over the threads (each tau sums about n rows: even shares), each
    # share summed by the compiled kernel without the GIL; every tau as the serial kernel sums it
    out = np.empty((len(m), x.shape[1]))
    shares = [slice(t, None, threads) for t in range(min(threads, len(m)))]
    with ThreadPoolExecutor(max_workers=len(shares) - 1, thread_name_prefix="adev") as pool:
        others = [pool.submit(allan_kernel.oadev_serial, x, m[share]) for share in shares[1:]]
        out[shares[0]] = allan_kernel.oadev_serial(x, m[shares[0]])
        for share, done in zip(shares[1:], others, strict=True):
            out[share] = done.result()
    return out


def load_kernels() -> None:
    """Load the compiled kernels (``allan_kernel.warm_up``) into this process before they run on
    other threads (numba's first call in a process costs 0.3-0.5 s, less once numba is loaded)."""
    from pendsim_mj.allan import kernel as allan_kernel  # start-up: numba and its compiled kernels, once needed

    allan_kernel.warm_up()


@dataclasses.dataclass(frozen=True)
class AllanCurve:
    """One axis' Allan deviation.

    Attributes:
      tau_s: (k,) averaging times, s.
      adev: (k,) overlapping Allan deviation, units of the data.
      low, high: (k,) confidence interval bounds at ``confidence``.
      edf: (k,) equivalent degrees of freedom.
      alpha: (k,) noise type used for the edf (0 white, -1 flicker, -2 random walk of the data).
      confidence: the interval's probability (0.683: 1 sigma).
      n_samples: samples in the record.
      rate_hz: sampling rate.
    """

    tau_s: np.ndarray
    adev: np.ndarray
    low: np.ndarray
    high: np.ndarray
    edf: np.ndarray
    alpha: np.ndarray
    confidence: float
    n_samples: int
    rate_hz: float


def local_slopes(tau_s: np.ndarray, adev: np.ndarray) -> np.ndarray:
    """d log(adev) / d log(tau) at each tau (central differences, one-sided at the ends)."""
    return np.gradient(np.log(adev), np.log(tau_s))


def _noise_alpha(slopes: np.ndarray) -> np.ndarray:
    """Power-law noise type of frequency data from the ADEV slope mu/2: alpha = -2 slope - 1."""
    return np.clip(np.rint(-2.0 * slopes - 1.0), -2, 1).astype(int)


def allan_curves(y: np.ndarray, rate_hz: float, *, confidence: float = ONE_SIGMA, threads: int = 2) -> list[AllanCurve]:
    """Allan deviation with confidence intervals for each column of y (n, a)."""
    y = np.asarray(y, dtype=float)
    return curves_of_phase(phase(y), rate_hz, confidence=confidence, threads=threads)


def curves_of_phase(
    x: np.ndarray, rate_hz: float, *, confidence: float = ONE_SIGMA, threads: int = 2
) -> list[AllanCurve]:
    """``allan_curves`` of the data whose phase (``phase``) is x (n+1, a): one curve per column."""
    n = len(x) - 1
    return curves_of_deviations(adev_of_phase(x, tau_grid(n), threads=threads), n, rate_hz, confidence=confidence)


def curves_of_deviations(
    adev: np.ndarray, n_samples: int, rate_hz: float, *, confidence: float = ONE_SIGMA
) -> list[AllanCurve]:
    """The curves (with confidence intervals) of the deviations adev (k, a) that ``adev_of_phase``
    gave on ``tau_grid(n_samples)`` for a record of n_samples at rate_hz: one curve per column."""
    n = n_samples
    m = tau_grid(n)
    tau = m / rate_hz
    edf_of = functools.cache(
        lambda al, k: edf_overlapping(al, k, n + 1)
    )  # the axes of a record share m and N, and mostly the noise type
    curves = []
    for j in range(adev.shape[1]):
        dev = adev[:, j]
        if np.any(dev <= 0):  # a constant axis: no noise to analyse
            alpha = np.zeros(len(m), int)
            edf = np.full(len(m), np.nan)
            curves.append(AllanCurve(tau, dev, dev.copy(), dev.copy(), edf, alpha, confidence, n, rate_hz))
            continue
        alpha = _noise_alpha(local_slopes(tau, dev))
        edf = np.array([edf_of(int(al), int(k)) for al, k in zip(alpha, m, strict=True)])
        low, high = confidence_interval(dev, edf, confidence)
        curves.append(AllanCurve(tau, dev, low, high, edf, alpha, confidence, n, rate_hz))
    return curves


def confidence_interval(dev: np.ndarray, edf: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """``allantools.confidence_interval`` (chi-squared, NIST SP1065 eq. 45) for arrays: the
    (low, high) bounds of the deviations dev (k,) with edf (k,) degrees of freedom. The chi-squared
    quantile is scipy.stats' ``chi2.ppf`` as scipy computes it, 2 gammaincinv(edf / 2, p), without
    importing scipy.stats (NaN where edf is not positive, as there)."""
    from scipy.special import gammaincinv  # start-up: scipy.special only, for the intervals

    tail = min(abs(confidence), abs(confidence - 1)) / 2
    edf = np.asarray(edf, dtype=float)
    with np.errstate(invalid="ignore"):
        upper = np.where(edf > 0, 2 * gammaincinv(edf / 2, 1 - tail), np.nan)
        lower = np.where(edf > 0, 2 * gammaincinv(edf / 2, tail), np.nan)
    low = np.sqrt(edf * dev * dev / upper)
    high = np.sqrt(edf * dev * dev / lower)
    return low, high


# Greenhall's tables (Greenhall 2004, Tables 2 and 3) for the Allan variance (d = 2), by alpha.
_TABLE2_D2 = {1: (790.0, 410.0), 0: (2.0 / 3.0, 1.0 / 3.0), -1: (0.852, 0.375), -2: (1.079, 0.368)}
_TABLE3_D2 = (15.23, 12.0)  # alpha = 1
_J_MAX = 100


def edf_overlapping(alpha: int, m: int, n_phase: int) -> float:
    """Equivalent degrees of freedom of the overlapping Allan variance (second differences, d = 2;
    stride 1, unmodified) at averaging factor m of n_phase phase points, for the power-law noise
    alpha (1 flicker PM, 0 white FM, -1 flicker FM, -2 random-walk FM): Greenhall's algorithm
    (Greenhall 2004, cases 2 and 3 with F = S = m; the same arithmetic as
    ``allantools.edf_greenhall(alpha, 2, m, n_phase, overlapping=True)``)."""
    if alpha not in _TABLE2_D2:
        raise ParameterError(f"edf_overlapping: alpha must be 1, 0, -1 or -2, got {alpha!r}")
    d = 2
    length = m / m + m * d  # the filter's length in phase samples
    big_m = 1 + np.floor(m * (n_phase - length) / m)
    j = min(big_m, (d + 1) * m)
    r = big_m / m
    if alpha <= 0:  # case 2
        if j <= _J_MAX:
            f = m if m * (d + 1) <= _J_MAX else math.inf
            inv = (1.0 / (pow(_sz(0, f, alpha), 2) * big_m)) * _basic_sum(j, big_m, m, f, alpha)
        elif r > d + 1:
            a0, a1 = _TABLE2_D2[alpha]
            inv = (1.0 / r) * (a0 - a1 / r)
        else:
            inv = (1.0 / (pow(_sz(0, math.inf, alpha), 2) * _J_MAX)) * _basic_sum(
                _J_MAX, _J_MAX, _J_MAX / r, math.inf, alpha
            )
        return float(1.0 / inv)
    b0, b1 = _TABLE3_D2  # case 3: alpha = 1
    if j <= _J_MAX:
        inv = (1.0 / (pow(_sz(0, m, 1), 2) * big_m)) * _basic_sum(j, big_m, m, m, 1)
    elif r > d + 1:
        a0, a1 = _TABLE2_D2[1]
        inv = (1.0 / (pow(b0 + b1 * np.log(m), 2) * r)) * (a0 - a1 / r)
    else:
        m_prime = _J_MAX / r
        inv = (1.0 / (pow(b0 + b1 * np.log(m), 2) * _J_MAX)) * _basic_sum(_J_MAX, _J_MAX, m_prime, m_prime, 1)
    return float(1.0 / inv)


def _basic_sum(j: float, big_m: float, s: float, f: float, alpha: int) -> float:
    """Greenhall's basic sum (2004, eq. 10) for d = 2."""
    first = pow(_sz(0, f, alpha), 2)
    second = (1 - float(j) / float(big_m)) * pow(_sz(float(j) / float(s), f, alpha), 2)
    third = 0.0
    for i in range(1, int(j)):
        third += 2 * (1.0 - float(i) / float(big_m)) * pow(_sz(float(i) / float(s), f, alpha), 2)
    return float(first + second + third)


def _sz(t: float, f: float, alpha: int) -> float:
    """Greenhall's s_z (2004, eq. 9) for d = 2: the second difference of s_x."""
    return (
        6 * _sx(t, f, alpha) - 4 * _sx(t - 1.0, f, alpha) - 4 * _sx(t + 1.0, f, alpha)
        + _sx(t - 2.0, f, alpha) + _sx(t + 2.0, f, alpha)
    )  # fmt: skip


def _sx(t: float, f: float, alpha: int) -> float:
    """Greenhall's s_x (2004, eq. 8)."""
    if f == math.inf:
        return _sw(t, alpha + 2)
    return pow(f, 2) * (2 * _sw(t, alpha) - _sw(t - 1.0 / float(f), alpha) - _sw(t + 1.0 / float(f), alpha))


def _sw(t: float, alpha: int) -> float:
    """Greenhall's s_w (2004, eq. 7): |t|^(1 - alpha) up to sign, with a log for odd alpha."""
    if alpha == 2:
        return -np.abs(t)
    if alpha == 1:
        return 0 if t == 0 else pow(t, 2) * np.log(np.abs(t))
    if alpha == 0:
        return np.abs(pow(t, 3))
    if alpha == -1:
        return 0 if t == 0 else pow(t, 4) * np.log(np.abs(t))
    if alpha == -2:
        return np.abs(pow(t, 5))
    if alpha == -3:
        return 0 if t == 0 else pow(t, 6) * np.log(np.abs(t))
    return np.abs(pow(t, 7))  # alpha = -4


@dataclasses.dataclass(frozen=True)
class NoiseTerms:
    """IEEE 952 terms of one curve (None where the record does not resolve the term: ``noise_terms``).

    white: N, units/sqrt(Hz) = units*sqrt(s) (velocity or angle random walk): adev N / sqrt(tau).
    bias_instability: B, units: the flat level adev 0.664 B.
    bias_instability_tau_s: where the flat part shows most (B's largest share of the curve), s.
    rate_random_walk: K, units/sqrt(s): adev K sqrt(tau / 3).
    unresolved: the curve rises above the white noise at long tau, but the record cannot tell
      bias instability from a random walk (either one fits it alike): neither is given.
    """

    white: float | None
    bias_instability: float | None
    bias_instability_tau_s: float | None
    rate_random_walk: float | None
    unresolved: bool = False


# The noise model fitted to the Allan variance (IEEE 952 annex C): sigma^2(tau) = 3 Q^2 / tau^2
# (quantisation) + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2 (rate ramp); Q and R
# are fitted so that they do not pass for N or K, and not reported.
_TERMS = ("Q", "N", "B", "K", "R")
SIGNIFICANT_CHI2 = 9.0
"""A term is given only if the best fit without it is worse by this much (the weighted squared
residual, scaled by the fit's own residual per degree of freedom where that exceeds 1: the curve's
points overlap and are correlated): about three standard deviations."""
DOMINANT_SHARE = 0.5  # ... and only if it makes at least this share of the curve's variance at some tau
DOMINANT_EDF = 10.0  # ... where the curve's estimate has at least this many degrees of freedom: on white noise
# alone (a new user's recordings) a flat part "dominated" the last tau of a 1 h record (T / tau = 10, about 5
# degrees of freedom) and gave B there


def _basis(tau: np.ndarray) -> np.ndarray:
    """(k, 5) each term's Allan variance per unit coefficient (``_TERMS``) at tau (k,) s."""
    return np.stack([3.0 / tau**2, 1.0 / tau, np.full_like(tau, BIAS_INSTABILITY_FACTOR**2), tau / 3.0,
                     tau**2 / 2.0], axis=1)  # fmt: skip


def _best_fit(a: np.ndarray, b: np.ndarray, allowed: tuple[int, ...]) -> tuple[float, np.ndarray]:
    """Non-negative least squares of a[:, allowed] c = b by trying every subset of the allowed
    columns (five at most: exact, and no scipy.optimize at start-up); (residual, c (5,))."""
    best, coef = math.inf, np.zeros(a.shape[1])
    for mask in range(1, 1 << len(allowed)):
        cols = [j for k, j in enumerate(allowed) if mask >> k & 1]
        c, *_ = np.linalg.lstsq(a[:, cols], b, rcond=None)
        if np.any(c < 0):
            continue
        residual = float(np.sum((a[:, cols] @ c - b) ** 2))
        if residual < best:
            best, coef = residual, np.zeros(a.shape[1])
            coef[cols] = c
    return best, coef


def noise_terms(curve: AllanCurve) -> NoiseTerms:
    """N, B and K of a curve: the noise model above fitted to its Allan variance with non-negative
    coefficients, each point weighted by its estimate's relative spread (sqrt(edf / 2) / sigma^2).
    A term is given where the record resolves it: significant (``SIGNIFICANT_CHI2``) and dominant
    somewhere (``DOMINANT_SHARE``). Where the long-tau rise is significant but neither bias
    instability nor a random walk alone is (each fits it as well as the other), ``unresolved``.

    Reading each term off the slope lines of the curve (IEEE 952's graphical method, pendsim's
    until 2026-11-28) took the crossover of a weak random walk for bias instability: a record with
    white noise and K = 5e-6 rad/s/sqrt(s), no B, reported B on 10 of 12 axes and K on 2."""
    tau, dev = curve.tau_s, curve.adev
    if len(tau) < 3 or np.any(dev <= 0):
        return NoiseTerms(None, None, None, None)
    variance = dev**2
    edf = np.where(np.isfinite(curve.edf), curve.edf, 1e6)  # NaN edf: constant data (no spread)
    weight = np.sqrt(edf / 2.0) / variance
    basis = _basis(tau)
    a, b = basis * weight[:, None], variance * weight
    everything = tuple(range(len(_TERMS)))
    residual, coef = _best_fit(a, b, everything)
    scale = max(1.0, residual / max(1, len(b) - int(np.count_nonzero(coef))))
    parts = basis * coef
    share = parts / parts.sum(axis=1, keepdims=True)
    firm = edf >= DOMINANT_EDF  # a term's dominance counts where the curve's estimate is firm

    def resolved(j: int) -> bool:
        if coef[j] <= 0 or not np.any((share[:, j] >= DOMINANT_SHARE) & firm):
            return False
        without, _ = _best_fit(a, b, tuple(i for i in everything if i != j))
        return (without - residual) / scale > SIGNIFICANT_CHI2

    found = {name: math.sqrt(coef[j]) if resolved(j) else None for j, name in enumerate(_TERMS)}
    rising = [j for j in (2, 3, 4) if coef[j] > 0]
    unresolved = False
    if rising and all(found[_TERMS[j]] is None for j in rising):
        white_only, _ = _best_fit(a, b, (0, 1))
        rise = np.any((parts[:, 2:].sum(axis=1) >= DOMINANT_SHARE * parts.sum(axis=1)) & firm)
        unresolved = bool(rise) and (white_only - residual) / scale > SIGNIFICANT_CHI2
    b_tau = float(tau[int(np.argmax(share[:, 2]))]) if found["B"] is not None else None
    return NoiseTerms(found["N"], found["B"], b_tau, found["K"], unresolved)


@dataclasses.dataclass(frozen=True)
class SamplingReport:
    """How uniform a record's timestamps are.

    gaps: (index, start time s, missing duration s) where an interval exceeds 1.5 nominal steps.
    irregular: intervals off the nominal step by more than 10 % that are not gaps.
    """

    nominal_dt_s: float
    gaps: list[tuple[int, float, float]]
    irregular: int
    max_deviation_s: float

    @property
    def uniform(self) -> bool:
        return not self.gaps and self.irregular == 0

    def describe(self) -> str:
        parts = []
        if self.gaps:
            largest = max(self.gaps, key=lambda g: g[2])
            parts.append(
                f"{len(self.gaps)} gap(s), the largest {largest[2]:.3f} s missing after t = {largest[1]:.3f} s"
            )
        if self.irregular:
            parts.append(f"{self.irregular} irregular interval(s), up to {self.max_deviation_s * 1e3:.2f} ms off")
        return "; ".join(parts) if parts else "uniform"


def check_sampling(t_ns: np.ndarray, rate_hz: float) -> SamplingReport:
    """Gaps and irregular intervals in integer-ns timestamps nominally 1/rate_hz apart."""
    nominal = NS_PER_S / rate_hz
    dt = np.diff(np.asarray(t_ns, dtype=np.int64)).astype(float)
    gap = dt > 1.5 * nominal
    irregular = (np.abs(dt - nominal) > 0.1 * nominal) & ~gap
    gaps = [(int(i), seconds(float(t_ns[i])), seconds(float(dt[i] - nominal))) for i in np.flatnonzero(gap)]
    deviation = seconds(float(np.max(np.abs(dt - nominal)))) if len(dt) else 0.0
    return SamplingReport(seconds(nominal), gaps, int(irregular.sum()), deviation)


MOTION_WINDOW_S = 0.1  # the gyro's turning rate is averaged over this before it counts as motion


@dataclasses.dataclass(frozen=True)
class Motion:
    """How a node turns during a recording that should be static.

    Attributes:
      rate_rad_s: (n,) magnitude of the gyro less its median (the bias), averaged over
        MOTION_WINDOW_S, rad/s.
      largest_rad_s: its largest value, rad/s; at index ``largest_index``.
    """

    rate_rad_s: np.ndarray
    largest_rad_s: float
    largest_index: int

    @property
    def moving(self) -> np.ndarray:
        """(n,) True where the node turns faster than MIN_MOTION_RAD_S (validate's "no motion")."""
        return self.rate_rad_s > MIN_MOTION_RAD_S

    @property
    def static(self) -> bool:
        return not bool(self.moving.any())


def gyro_motion(gyro_rad_s: np.ndarray, rate_hz: float) -> Motion:
    """How a node whose (n, 3) gyro samples come at ``rate_hz`` turns (see ``Motion``). Noise
    (the BNO055's 0.001-0.002 rad/s) averages to a few 0.001 rad/s; a pendulum swinging by
    1 deg turns at 0.09 rad/s at its centre."""
    g = np.asarray(gyro_rad_s, dtype=float)
    if len(g) == 0:
        return Motion(np.zeros(0), 0.0, 0)
    speed = np.zeros(len(g))
    for j in range(g.shape[1]):  # column by column: temporaries of one column, not of the (n, 3) data
        d = g[:, j] - np.median(g[:, j])
        speed += d * d
    np.sqrt(speed, out=speed)
    k = min(len(speed), max(1, round(MOTION_WINDOW_S * rate_hz)))
    rate = np.convolve(speed, np.ones(k) / k, mode="same")
    i = int(np.argmax(rate))
    return Motion(rate, float(rate[i]), i)


MOTION_MARGIN_S = 0.5
"""Samples this close to any node's motion are not static (``still_samples``): the turning rate is
averaged over MOTION_WINDOW_S and crosses MIN_MOTION_RAD_S only after the motion has begun (a
coupled pendulum, moved through the springs, a second or more after the release)."""


def motion_intervals_s(t_s: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """(k, 2) first and last instant (s, as t_s) of each run of moving samples (``Motion.moving``)."""
    edges = np.diff(np.concatenate([[0], np.asarray(moving, dtype=np.int8), [0]]))
    first, last = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return np.stack([t_s[first], t_s[last]], axis=1) if len(first) else np.zeros((0, 2))


def still_samples(t_s: np.ndarray, intervals_s: np.ndarray, margin_s: float = MOTION_MARGIN_S) -> np.ndarray:
    """(n,) True at the instants t_s (s) farther than ``margin_s`` from every interval of
    ``intervals_s`` (k, 2): e.g. every node's motion (``motion_intervals_s`` of each, stacked),
    so that a static stretch ends before the earliest motion onset of any node."""
    if not len(intervals_s):
        return np.ones(len(t_s), bool)
    order = np.argsort(intervals_s[:, 0], kind="stable")
    starts = intervals_s[order, 0] - margin_s
    reach = np.maximum.accumulate(intervals_s[order, 1]) + margin_s  # the farthest end so far
    i = np.searchsorted(starts, t_s, side="right") - 1
    return ~((i >= 0) & (t_s <= reach[np.maximum(i, 0)]))


def longest_uniform_segment(t_ns: np.ndarray, rate_hz: float, usable: np.ndarray | None = None) -> slice:
    """The longest run of samples with no gap and no irregular interval (and, given a (n,) bool
    ``usable``, only usable samples: e.g. the static ones)."""
    nominal = NS_PER_S / rate_hz
    dt = np.diff(np.asarray(t_ns, dtype=np.int64)).astype(float)
    broken = np.abs(dt - nominal) > 0.1 * nominal
    if usable is not None:
        broken |= ~usable[1:] | ~usable[:-1]
    bad = np.flatnonzero(broken)
    edges = np.concatenate([[-1], bad, [len(t_ns) - 1]])
    lengths = np.diff(edges)
    i = int(np.argmax(lengths))
    return slice(int(edges[i] + 1), int(edges[i + 1] + 1))
