"""Allan deviation of static IMU records, with confidence intervals and noise terms (IEEE 952).

- **Deviations**: the overlapping Allan deviation of each axis (frequency-type data: rates and
  accelerations) on a log-spaced tau grid, 12 values per decade from 1/fs to a tenth of the
  record. Computed exactly here rather than with ``allantools.oadev``: on this project's 2-core
  machine that took 1.7 s per axis for a 6 h, 80 Hz record on a 90-tau grid (20 s for 12 axes,
  against the 10 s budget for the whole analysis); this kernel sums the second differences of the
  phase in cache-sized blocks over the axes, the axes split over threads (numpy releases the GIL
  in its loops; no worker processes, no copy of the data), and
  equals ``allantools.oadev`` to 1e-12 (tests/test_allan.py).
- **Confidence intervals**: ``allantools.edf_greenhall`` (equivalent degrees of freedom for the
  overlapping estimator) and ``allantools.confidence_interval`` (chi-squared), with the noise type
  of each tau identified from the local log-log slope (-1/2 white, 0 flicker, +1/2 random walk).
- **Noise terms** read from the curve: white noise N (velocity or angle random walk) as the value
  at tau = 1 s of the slope -1/2 line through the points where the slope is -1/2; rate random
  walk K as the value at tau = 3 s of the slope +1/2 line (sigma = K sqrt(tau / 3)); bias
  instability B as the flat part (slope within +-0.15, where the estimate is reliable, with the
  N and K contributions subtracted) divided by 0.664 (= sqrt(2 ln 2 / pi)). A term whose slope
  the curve never shows is None.
- **Sampling**: Allan deviation assumes uniform sampling; ``check_sampling`` finds gaps and
  irregular timestamps so that they are reported, not silently analysed.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from concurrent.futures import ThreadPoolExecutor

import allantools
import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors import MIN_MOTION_RAD_S

TAUS_PER_DECADE = 12
ONE_SIGMA = math.erf(1 / math.sqrt(2))  # 0.6827: 1-sigma confidence
BIAS_INSTABILITY_FACTOR = math.sqrt(2 * math.log(2) / math.pi)  # 0.664
_BLOCK_ROWS = 8192


def tau_grid(n_samples: int, per_decade: int = TAUS_PER_DECADE) -> np.ndarray:
    """Averaging factors m (integers, tau = m / fs) from 1 to n_samples / 10, log-spaced."""
    top = n_samples / 10
    if top < 2:
        raise ParameterError(f"need at least 20 samples for an Allan deviation, got {n_samples}")
    count = int(math.log10(top) * per_decade) + 1
    return np.unique(np.rint(np.logspace(0, math.log10(top), count)).astype(np.int64))


def _oadev_kernel(y: np.ndarray, m: np.ndarray) -> np.ndarray:
    """sqrt(sum d^2 / (2 m^2 (n+1-2m))) with d the phase second difference at lag m; (len(m), a).
    Phase in units of samples: the caller's units cancel (adev of y in y's units)."""
    n, a = y.shape
    x = np.empty((n + 1, a))
    x[0] = 0.0
    np.cumsum(y, axis=0, out=x[1:])
    out = np.empty((len(m), a))
    tmp = np.empty((_BLOCK_ROWS, a))
    for i, k in enumerate(m):
        k = int(k)
        rows = n + 1 - 2 * k
        total = np.zeros(a)
        for r0 in range(0, rows, _BLOCK_ROWS):
            r1 = min(r0 + _BLOCK_ROWS, rows)
            t = tmp[: r1 - r0]
            np.multiply(x[r0 + k : r1 + k], -2.0, out=t)
            t += x[r0 + 2 * k : r1 + 2 * k]
            t += x[r0:r1]
            total += np.einsum("ij,ij->j", t, t)
        out[i] = np.sqrt(total / (2.0 * k * k * rows))
    return out


def overlapping_adev(y: np.ndarray, m: np.ndarray, *, threads: int = 2) -> np.ndarray:
    """Overlapping Allan deviation of frequency-type data.

    Args:
      y: (n,) or (n, a) samples (a axes), uniformly sampled.
      m: averaging factors (tau = m / fs), each <= (n - 1) / 2.
      threads: threads over the axes (1 = this thread only); one process, the data not copied.

    Returns:
      (len(m),) or (len(m), a) deviations in the units of y.
    """
    y = np.asarray(y, dtype=float)
    flat = y.ndim == 1
    y2 = y[:, None] if flat else y
    m = np.asarray(m, dtype=np.int64)
    if np.any(m < 1) or np.any(2 * m > len(y2)):
        raise ParameterError(f"averaging factors must be in 1..{len(y2) // 2}, got {m.min()}..{m.max()}")
    a = y2.shape[1]
    nthread = min(threads, a) if len(y2) * a > 2_000_000 else 1
    if nthread <= 1:
        out = _oadev_kernel(y2, m)
    else:
        bounds = np.linspace(0, a, nthread + 1).astype(int)
        with ThreadPoolExecutor(nthread) as pool:
            parts = list(pool.map(lambda b: _oadev_kernel(y2[:, b[0] : b[1]], m), itertools.pairwise(bounds)))
        out = np.concatenate(parts, axis=1)
    return out[:, 0] if flat else out


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
    if y.ndim == 1:
        y = y[:, None]
    n = len(y)
    m = tau_grid(n)
    adev = overlapping_adev(y, m, threads=threads)
    tau = m / rate_hz
    curves = []
    for j in range(y.shape[1]):
        dev = adev[:, j]
        if np.any(dev <= 0):  # a constant axis: no noise to analyse
            alpha = np.zeros(len(m), int)
            edf = np.full(len(m), np.nan)
            curves.append(AllanCurve(tau, dev, dev.copy(), dev.copy(), edf, alpha, confidence, n, rate_hz))
            continue
        alpha = _noise_alpha(local_slopes(tau, dev))
        edf = np.array(
            [
                allantools.edf_greenhall(alpha=int(al), d=2, m=int(k), N=n + 1, overlapping=True)
                for al, k in zip(alpha, m, strict=True)
            ]
        )
        bounds = np.array([allantools.confidence_interval(d, e, ci=confidence) for d, e in zip(dev, edf, strict=True)])
        curves.append(AllanCurve(tau, dev, bounds[:, 0], bounds[:, 1], edf, alpha, confidence, n, rate_hz))
    return curves


@dataclasses.dataclass(frozen=True)
class NoiseTerms:
    """IEEE 952 terms read from one curve (None where the curve shows no such slope).

    white: N, units/sqrt(Hz) = units*sqrt(s) (velocity or angle random walk): adev at tau = 1 s
      on the -1/2 line.
    bias_instability: B, units: flat level / 0.664.
    bias_instability_tau_s: where the flat part is (its middle), s.
    rate_random_walk: K, units/sqrt(s): adev at tau = 3 s on the +1/2 line.
    """

    white: float | None
    bias_instability: float | None
    bias_instability_tau_s: float | None
    rate_random_walk: float | None


def noise_terms(curve: AllanCurve, *, slope_tolerance: float = 0.15, min_edf: float = 30.0) -> NoiseTerms:
    """Read N, B and K from a curve (see the module docstring)."""
    tau, dev = curve.tau_s, curve.adev
    if np.any(dev <= 0):
        return NoiseTerms(None, None, None, None)
    slopes = local_slopes(tau, dev)
    reliable = ~(curve.edf < min_edf)  # NaN edf counts as reliable (it is only for constant data)

    def line_value(target: float, at_tau: float) -> float | None:
        near = (np.abs(slopes - target) <= slope_tolerance / 2) & reliable
        if not np.any(near):
            near = (np.abs(slopes - target) <= slope_tolerance) & reliable
        if not np.any(near):
            return None
        # the fixed-slope line through those points, in log space: log dev = c + target log tau
        c = np.mean(np.log(dev[near]) - target * np.log(tau[near]))
        return float(math.exp(c + target * math.log(at_tau)))

    white = line_value(-0.5, 1.0)
    rrw = line_value(0.5, 3.0)
    flat = (np.abs(slopes) <= slope_tolerance) & reliable
    b, b_tau = None, None
    if np.any(flat):
        # The flat level with the white and random-walk parts removed: sigma_B^2 =
        # sigma^2 - N^2/tau - K^2 tau/3. Where little is left, the "flat" points are only the
        # crossover from -1/2 to +1/2, not bias instability.
        variance = dev[flat] ** 2
        rest = variance - (white or 0.0) ** 2 / tau[flat] - (rrw or 0.0) ** 2 * tau[flat] / 3
        level = float(np.median(rest))
        if level > 0.25 * float(np.median(variance)):
            b = math.sqrt(level) / BIAS_INSTABILITY_FACTOR
            b_tau = float(np.exp(np.median(np.log(tau[flat]))))
    return NoiseTerms(white, b, b_tau, rrw)


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
    nominal = 1e9 / rate_hz
    dt = np.diff(np.asarray(t_ns, dtype=np.int64)).astype(float)
    gap = dt > 1.5 * nominal
    irregular = (np.abs(dt - nominal) > 0.1 * nominal) & ~gap
    gaps = [(int(i), float(t_ns[i]) * 1e-9, float(dt[i] - nominal) * 1e-9) for i in np.flatnonzero(gap)]
    deviation = float(np.max(np.abs(dt - nominal))) * 1e-9 if len(dt) else 0.0
    return SamplingReport(nominal * 1e-9, gaps, int(irregular.sum()), deviation)


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
    speed = np.linalg.norm(g - np.median(g, axis=0), axis=1)
    k = min(len(speed), max(1, round(MOTION_WINDOW_S * rate_hz)))
    rate = np.convolve(speed, np.ones(k) / k, mode="same")
    i = int(np.argmax(rate))
    return Motion(rate, float(rate[i]), i)


def longest_uniform_segment(t_ns: np.ndarray, rate_hz: float, usable: np.ndarray | None = None) -> slice:
    """The longest run of samples with no gap and no irregular interval (and, given a (n,) bool
    ``usable``, only usable samples: e.g. the static ones)."""
    nominal = 1e9 / rate_hz
    dt = np.diff(np.asarray(t_ns, dtype=np.int64)).astype(float)
    broken = np.abs(dt - nominal) > 0.1 * nominal
    if usable is not None:
        broken |= ~usable[1:] | ~usable[:-1]
    bad = np.flatnonzero(broken)
    edges = np.concatenate([[-1], bad, [len(t_ns) - 1]])
    lengths = np.diff(edges)
    i = int(np.argmax(lengths))
    return slice(int(edges[i] + 1), int(edges[i + 1] + 1))
