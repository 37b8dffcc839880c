"""Time on real recordings: each node's clock against the recorder's, where the fused values
belong in time, and which parts of a run the samples cover.

- A node stamps its samples with its own clock; the recorder logs each message when it arrives,
  a variable transport latency later. ``fit_clock`` finds recorder time = offset + rate x stamp
  under the points (stamp, log time): the latency jitter lies above it.
- Gaps: samples are lost (often in bursts). A *covered segment* is a run of samples whose
  spacing never exceeds ``max_gap_s``; nothing is ever interpolated across a longer gap.
"""

from __future__ import annotations

import bisect
import dataclasses
import itertools
import math
from collections.abc import Sequence
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import ParameterError, RecordingError

Floats = NDArray[np.float64]

DEFAULT_MAX_GAP_S = 0.1
ROUGHNESS_BLOCK = 65536
"""Samples taken at once by the whole-run loops here (``fit_clock``, ``roughness``,
``fusion_phase``): bounds their memory (a few MB) whatever the run's length; the results are the
whole run's."""


@dataclasses.dataclass(frozen=True)
class ClockRelation:
    """Recorder time (s) = offset_s + rate x (node stamp - stamp0_s) (s)."""

    offset_s: float
    rate: float
    stamp0_s: float = 0.0

    @property
    def drift_ppm(self) -> float:
        """How fast the node's clock runs against the recorder's, ppm (+: the node's runs fast)."""
        return (1.0 / self.rate - 1.0) * 1e6

    @overload
    def to_recorder(self, stamp_s: float) -> float: ...

    @overload
    def to_recorder(self, stamp_s: ArrayLike) -> Floats: ...

    def to_recorder(self, stamp_s: float | ArrayLike) -> float | Floats:
        """Recorder time (s) of node stamps (s): a float for a float (the live loop maps one packet
        at a time: numpy's scalar round trip cost more than the arithmetic), else an array."""
        stamp = stamp_s if isinstance(stamp_s, float) else np.asarray(stamp_s, dtype=float)
        return self.offset_s + self.rate * (stamp - self.stamp0_s)

    def to_recorder_in_place(self, stamp_s: np.ndarray) -> np.ndarray:
        """``to_recorder`` of float64 stamps (n,) computed in their own array, which it returns
        (the same operations, so the same values; a long run: no second (n,) array)."""
        stamp_s -= self.stamp0_s
        stamp_s *= self.rate
        stamp_s += self.offset_s
        return stamp_s


MAX_DRIFT_PPM = 1000.0


class ClockFit:
    """The lower-envelope clock fit, online: ``add(stamp_s, arrival_s)`` for every message as it
    arrives, ``relation()`` for the current map.

    A message stamped x (node clock) arrives at y = a + b x + delay, the delay never negative and
    near its minimum for some messages. So the true line lies on or under every point, touching
    the lowest: of those lines, the one closest to all points (maximise a + b mean(x) subject to
    a + b x_i <= y_i; the linear-programming estimate of Moon, Skelly and Towsley, 1999) is the
    edge of the points' lower convex hull that spans their mean stamp. Least squares would follow
    the mean delay instead, and every burst of delay would move it. The hull is kept incrementally
    (O(1) amortised per point; few vertices). Points not after the last one (reordered or
    duplicated messages, which arrived late anyway) are skipped. The rate is held within
    ``max_drift_ppm`` of 1 (early in a run, with a short span, an edge's slope is noise).
    """

    def __init__(self, *, max_drift_ppm: float = MAX_DRIFT_PPM) -> None:
        self.max_drift_ppm = max_drift_ppm
        self._x0: float | None = None
        self._hx: list[float] = []  # lower hull vertices, stamp relative to x0
        self._hy: list[float] = []
        self._n = 0
        self._sum_x = 0.0
        self._relation: ClockRelation | None = None

    @property
    def count(self) -> int:
        """Points used so far."""
        return self._n

    @property
    def span_s(self) -> float:
        """Node time covered by the points, s."""
        return self._hx[-1] - self._hx[0] if self._hx else 0.0

    def add(self, stamp_s: float, arrival_s: float) -> None:
        if self._x0 is None:
            self._x0 = stamp_s
        x = stamp_s - self._x0
        if self._hx and x <= self._hx[-1]:
            return
        hx, hy = self._hx, self._hy
        # Keep the chain convex from below: drop the last vertex while it lies on or above the
        # segment from the one before it to the new point.
        while len(hx) >= 2 and (hx[-1] - hx[-2]) * (arrival_s - hy[-2]) - (hy[-1] - hy[-2]) * (x - hx[-2]) <= 0:
            hx.pop()
            hy.pop()
        hx.append(x)
        hy.append(arrival_s)
        self._n += 1
        self._sum_x += x
        self._relation = None

    def relation(self) -> ClockRelation:
        """The current map (rate 1 through the lowest point until a second point arrives)."""
        if self._relation is not None:
            return self._relation
        if self._x0 is None:
            raise ValueError("no points yet")
        hx, hy = self._hx, self._hy
        bound = self.max_drift_ppm * 1e-6  # recorder per node time: 1 / (1 + drift)
        lo, hi = 1.0 / (1.0 + bound), 1.0 / (1.0 - bound)
        if len(hx) == 1:
            rate = 1.0
        else:
            mean_x = self._sum_x / self._n
            i = min(max(bisect.bisect_right(hx, mean_x) - 1, 0), len(hx) - 2)
            rate = (hy[i + 1] - hy[i]) / (hx[i + 1] - hx[i])
        rate = min(max(rate, lo), hi)
        # The highest line of that rate under every vertex (the optimum for a clamped rate).
        offset = min(y - rate * x for x, y in zip(hx, hy, strict=True))
        self._relation = ClockRelation(offset, rate, self._x0)
        return self._relation


def fit_clock(stamp_s: Floats, log_s: Floats) -> ClockRelation | None:
    """The relation of a node's stamps to the recorder's log times (``ClockFit`` over all of
    them), or None when the stamps do not behave as a clock (not increasing, or a rate off by more
    than 1 %)."""
    x = np.asarray(stamp_s, dtype=float)
    y = np.asarray(log_s, dtype=float)
    if len(x) < 2 or not np.all(np.diff(x) > 0):
        return None
    fit = ClockFit(max_drift_ppm=1e5)  # clamped at 10 %: a rate off by over 1 % is refused below
    for lo in range(0, len(x), ROUGHNESS_BLOCK):  # in blocks: no whole-run lists of Python floats
        for xi, yi in zip(x[lo : lo + ROUGHNESS_BLOCK].tolist(), y[lo : lo + ROUGHNESS_BLOCK].tolist(), strict=True):
            fit.add(xi, yi)
    relation = fit.relation()
    return relation if 0.99 < relation.rate < 1.01 else None


def fused_value_instants(stamp_s: Floats, fusion_rate_hz: float | None, phase_s: float = 0.0) -> Floats:
    """The instant (node clock, s) of the value a sample stamped ``stamp_s`` carries: the latest
    fusion tick (ticks at phase_s + k / fusion_rate_hz) at or before it; the stamp itself for a
    node without fusion timing (None)."""
    t = np.asarray(stamp_s, dtype=float)
    if not fusion_rate_hz:
        return t
    # phase_s + floor((t - phase_s) rate + 1e-9) / rate, each step in one new array (a long run)
    ticks = t - phase_s
    ticks *= fusion_rate_hz
    ticks += 1e-9
    np.floor(ticks, out=ticks)
    ticks /= fusion_rate_hz
    ticks += phase_s
    return ticks


def segments(t_s: Floats, max_gap_s: float) -> list[tuple[int, int]]:
    """Covered segments of sample instants t_s (n,), increasing: (start, stop) index ranges whose
    consecutive spacing is at most ``max_gap_s``."""
    t = np.asarray(t_s, dtype=float)
    if len(t) == 0:
        return []
    cuts = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    bounds = np.concatenate([[0], cuts, [len(t)]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(bounds)]


@dataclasses.dataclass(frozen=True)
class Coverage:
    """How much of a span one node's samples cover.

    Attributes:
      span_s: from the first to the last sample, s.
      samples: samples received.
      expected_samples: samples a node at the nominal rate would have sent over the span.
      covered_s: time inside covered segments (spacing <= max_gap_s), s.
      gaps: gaps longer than max_gap_s (never interpolated across).
      longest_gap_s: the longest spacing between samples, s.
      max_gap_s: the limit used, s.
    """

    span_s: float
    samples: int
    expected_samples: int
    covered_s: float
    gaps: int
    longest_gap_s: float
    max_gap_s: float

    @property
    def covered_fraction(self) -> float:
        return self.covered_s / self.span_s if self.span_s > 0 else 0.0

    @property
    def lost_fraction(self) -> float:
        """Share of the expected samples that did not arrive."""
        return max(0.0, 1.0 - self.samples / self.expected_samples) if self.expected_samples else 0.0

    def summary(self) -> dict[str, float | int]:
        return {
            "span_s": self.span_s,
            "samples": self.samples,
            "expected_samples": self.expected_samples,
            "lost_fraction": self.lost_fraction,
            "covered_s": self.covered_s,
            "covered_fraction": self.covered_fraction,
            "gaps_over_limit": self.gaps,
            "longest_gap_s": self.longest_gap_s,
            "max_gap_s": self.max_gap_s,
        }


def coverage(t_s: Floats, max_gap_s: float, nominal_rate_hz: float) -> Coverage:
    """The coverage of sample instants t_s (n,), increasing, by a node sending at
    ``nominal_rate_hz``."""
    t = np.asarray(t_s, dtype=float)
    if len(t) < 2:
        raise RecordingError(f"{len(t)} samples: too few to cover any time")
    step = np.diff(t)
    span = float(t[-1] - t[0])
    short = step <= max_gap_s
    covered = float(step.sum() if short.all() else step[short].sum())  # no gaps: no copy of the steps
    del short
    return Coverage(
        span_s=span,
        samples=len(t),
        expected_samples=round(span * nominal_rate_hz) + 1,
        covered_s=covered,
        gaps=int(np.count_nonzero(step > max_gap_s)),
        longest_gap_s=float(step.max()),
        max_gap_s=max_gap_s,
    )


GAP_PERIODS = 1.5
"""A spacing longer than this many nominal periods is a gap (samples lost), not a sampling step."""


def nominal_rate_hz(t_s: Floats) -> float:
    """The sending rate of a node that may lose samples, Hz: one over the slope of the instants
    against their sample numbers (least squares), a gap counting the periods it spans.

    The period is first the mean of the regular steps (repeated instants and gaps, steps longer
    than ``GAP_PERIODS`` median steps, left out); each step then counts rint(step / period)
    sample numbers, and the fit is done twice. Right for quantised stamps: an 80 Hz node
    stamping with millis() has steps of 12 and 13 ms whose median is either (83.3 or 76.9 Hz),
    while the fit averages the 1 ms ticks out over the whole run.

    Args:
      t_s: (n,) sample instants, increasing, s.
    """
    t = np.asarray(t_s, dtype=float)
    all_steps = np.diff(t)
    step = all_steps[all_steps > 0]
    if not len(step):
        raise RecordingError("no two samples at different instants: no sampling rate")
    regular = step[step <= GAP_PERIODS * float(np.median(step))]
    period = float(regular.sum()) / len(regular)
    centred = t - t.mean()
    for _ in range(2):
        k = np.concatenate([[0.0], np.cumsum(np.rint(np.maximum(all_steps, 0.0) / period))])
        k -= k.mean()
        period = float(np.dot(k, centred) / np.dot(k, k))
    return 1.0 / period


def check_max_gap(max_gap_s: float) -> None:
    if not (math.isfinite(max_gap_s) and 0 < max_gap_s <= 10):
        raise ParameterError(f"max_gap_s must be a finite number in (0, 10] s, got {max_gap_s!r}")


def _second_difference_sums(t: Floats, v: Floats, max_step_s: float, dv: Floats | None = None) -> tuple[float, int]:
    """(sum of squares, count) of the second divided differences of v (n, k) over t (n,), over
    triples whose spacing stays within ``max_step_s``; ``dv``: ``np.diff(v, axis=0)`` if the
    caller has it (the same v at many t: ``fusion_phase``)."""
    h = np.diff(t)
    h1, h2 = h[:-1], h[1:]
    ok = (h1 > 0) & (h2 > 0) & (h1 <= max_step_s) & (h2 <= max_step_s)
    if not ok.any():
        return 0.0, 0
    if dv is None:
        dv = np.diff(v, axis=0)
    if ok.all():  # the usual case: slices, no gathered copies (the same values)
        h1, h2, d1, d2 = h1[:, None], h2[:, None], dv[:-1], dv[1:]
    else:
        h1, h2, d1, d2 = h1[ok, None], h2[ok, None], dv[:-1][ok], dv[1:][ok]
    second = np.divide(d2, h2)  # (v[2:] - v[1:-1]) / h2 - (v[1:-1] - v[:-2]) / h1, in place
    second -= np.divide(d1, h1)
    second *= 2.0
    second /= h1 + h2
    second *= second
    return float(np.sum(second)), int(second.size)


def _blocks(n: int):
    """(lo, hi) sample ranges of ``ROUGHNESS_BLOCK`` triple centres each, overlapping by two
    samples: every triple of n samples lies in exactly one."""
    for lo in range(0, max(n - 2, 0), ROUGHNESS_BLOCK):
        yield lo, min(lo + ROUGHNESS_BLOCK + 2, n)


def roughness(t_s: Floats, values: Floats, max_step_s: float) -> float:
    """Mean square of the second divided differences of values (n, ...) over instants t_s (n,),
    over triples whose spacing stays within ``max_step_s``: small when the instants are where the
    values belong, large when they are jittered against them. Computed in blocks of
    ``ROUGHNESS_BLOCK`` samples (memory flat with n)."""
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(values).reshape(len(t), -1)
    total, count = 0.0, 0
    for lo, hi in _blocks(len(t)):
        s, c = _second_difference_sums(t[lo:hi], v[lo:hi].astype(float), max_step_s)
        total, count = total + s, count + c
    return total / count if count else 0.0


def fusion_phase_stretch(stamp_s: Floats, fusion_rate_hz: float, phase_s: float) -> tuple[float, float]:
    """The phases that give every sample the same fusion tick as ``phase_s`` does: (lo_s, hi_s],
    lo_s < phase_s <= hi_s (s; not reduced to one period). Within it the value instants
    (``fused_value_instants``) all move alike, so the values' own smoothness (``fusion_phase``)
    cannot tell its phases apart; a fit against the other node through the model can. Its ends
    are the samples' own phases in the fusion period (stamps mod 1 / fusion_rate_hz): 80 Hz
    samples of 100 Hz fusion on one clock fall at four, so the stretch is 2.5 ms wide; samples on
    a clock that drifts against the ticks spread over the period and narrow it."""
    period = 1.0 / fusion_rate_hz
    after = np.mod(np.asarray(stamp_s, dtype=float) - phase_s, period)  # each sample's time since its tick
    return phase_s - (period - float(np.max(after))), phase_s + float(np.min(after))


def fusion_phase(stamp_s: Floats, values: Floats, fusion_rate_hz: float, *, step_s: float = 0.00025) -> float:
    """Where a chip's fusion ticks fall on its node's clock (s in [0, 1 / fusion_rate_hz)), found
    from the data alone: the phase whose value instants (``fused_value_instants``) make the
    values (n, ...) (e.g. the gyro) smoothest in time."""
    period = 1.0 / fusion_rate_hz
    stamp = np.asarray(stamp_s, dtype=float)
    v = np.asarray(values).reshape(len(stamp), -1)
    max_step = 2.5 * float(np.median(np.diff(stamp)))
    phases = np.arange(0.0, period, step_s)
    sums, counts = np.zeros(len(phases)), np.zeros(len(phases))
    for lo, hi in _blocks(len(stamp)):  # block by block, every phase: memory flat with the run
        block = v[lo:hi].astype(float)
        dv = np.diff(block, axis=0)  # the same at every phase
        for j, p in enumerate(phases):
            instants = fused_value_instants(stamp[lo:hi], fusion_rate_hz, float(p))
            s, c = _second_difference_sums(instants, block, max_step, dv)
            sums[j] += s
            counts[j] += c
    costs = np.divide(sums, counts, out=np.zeros(len(phases)), where=counts > 0)
    # Within the stretch between two sample phases every value instant moves alike, so the
    # roughness is flat there: only the stretch is found, and its middle is taken (within
    # +-1/8 period of the truth at 80 Hz sampling of 100 Hz fusion; a common shift is absorbed by
    # the start fit).
    best = int(np.argmin(costs))
    flat = costs <= costs[best] * (1 + 1e-6) + 1e-300
    lo = hi = best
    n = len(phases)
    while flat[(lo - 1) % n] and best - lo < n - 1:
        lo -= 1
    while flat[(hi + 1) % n] and hi - lo < n - 1:
        hi += 1
    return float((0.5 * (lo + hi) * step_s) % period)


STEP_WINDOW = 16  # samples either side of a step whose times' medians measure it
STEP_FIT = 8  # samples either side whose values decide between readings a period apart (a quintic in time)
SAME_STEP_S = 0.1  # a step of the other node's column this near is the same clock's (``clock_steps``' known), s
MIN_CLOCK_STEP_S = 3e-4  # a step of the times smaller than this is left as it is, s
MAX_CLOCK_STEPS = 20  # more candidate steps than this: times too irregular to find steps in


@dataclasses.dataclass(frozen=True)
class ClockStep:
    """A step of a node's time column: the samples from ``index`` on carry times ``step_s`` later
    than a regular sampler's (s; negative: the clock was set back).

    Attributes:
      index: the first sample after the step.
      at_s: its time as the column gives it, s.
      step_s: the step removed, s.
      other_s: the reading a sample period away, where the times alone allow it (the step over a
        lost sample) and the values could not tell it apart (None: they did, or it was not
        possible).
    """

    index: int
    at_s: float
    step_s: float
    other_s: float | None = None

    def describe(self, node: str) -> str:
        """One line naming the step, for a warning."""
        line = f"{node}'s times step by {1e3 * self.step_s:+.1f} ms at {self.at_s:.3f} s (a clock step"
        if self.other_s is None:
            return line + ": its samples are regular around it); removed"
        return (
            line + f"; or {1e3 * self.other_s:+.1f} ms and a sample lost: its values do not tell which); "
            f"{1e3 * self.step_s:+.1f} ms removed"
        )


def _smoothest(t: Floats, values: Floats, split: int, readings: Floats) -> tuple[int, int | None]:
    """Which of the readings (k,) of a step between samples split - 1 and split of instants t (m,)
    makes values (m, c) smoothest across it (least squares quintic in time, the samples from
    ``split`` on moved back by the reading): (its index, None) where its residual is below half
    every other's; else (the smallest step among those within twice the least residual, the next
    smallest of them): the values do not tell them apart, and the fewest assumed is taken."""
    costs = []
    for step in readings:
        local = t - np.where(np.arange(len(t)) >= split, step, 0.0)
        local = (local - local.mean()) / max(float(np.ptp(local)), 1e-9)
        basis = np.vander(local, 6)
        fit, *_ = np.linalg.lstsq(basis, values, rcond=None)
        costs.append(float(np.sum((basis @ fit - values) ** 2)))
    cost = np.array(costs)
    close = np.flatnonzero(cost < 2.0 * cost.min())
    if len(close) == 1:
        return int(close[0]), None
    by_size = close[np.argsort(np.abs(readings[close]))]
    return int(by_size[0]), int(by_size[1])


def _step_sizes(off: Floats, candidates: NDArray[np.intp]) -> Floats:
    """The step (s) at each candidate c (between samples c and c + 1) of a time column whose
    steps less whole periods are ``off`` (n - 1,): the median of the times less the regular grid
    over STEP_WINDOW samples after it less that over STEP_WINDOW samples up to it."""
    grid = np.concatenate([[0.0], np.cumsum(off)])
    padded = np.concatenate([np.full(STEP_WINDOW, np.nan), grid, np.full(STEP_WINDOW, np.nan)])
    window = np.arange(STEP_WINDOW)
    before = np.nanmedian(padded[candidates[:, None] + 1 + window], axis=1)  # samples c - W + 1 .. c
    after = np.nanmedian(padded[candidates[:, None] + 1 + STEP_WINDOW + window], axis=1)  # c + 1 .. c + W
    result: Floats = after - before
    return result


def clock_steps(
    t_s: Floats, values: Floats, known: Sequence[tuple[float, float]] = ()
) -> tuple[Floats, list[ClockStep]]:
    """Steps of a regular sampler's time column (a logging host's clock set back or forward) found
    and removed: (the times (n,) with every step removed, the steps).

    The steps between samples, less the whole sample periods (``nominal_rate_hz``) each spans (at
    least one), are a regular sampler's timing jitter (a robust scale from their median absolute
    deviation); a step of the clock is one of them beyond ``MIN_CLOCK_STEP_S`` and ten times that
    scale whose times stay moved: the medians of the times less the regular grid over
    ``STEP_WINDOW`` samples after it and before it differ by it (a single late sample moves
    neither). Its size is that difference. From the times alone a step is known only to whole
    periods where the samples around it may have been lost (+10 ms at 80 Hz reads as -2.5 ms and
    a lost sample): of the readings a period apart that leave at least one period between the two
    samples, the one that makes ``values`` (n, c) (e.g. the gyro) smoothest across the step is
    taken; where the values do not tell (a pendulum at rest), the reading of a ``known`` step
    within SAME_STEP_S (the other node's column, stepped by the same host clock), else the
    smallest, and ``ClockStep.other_s`` names the next.

    Args:
      t_s: (n,) the column's times, increasing, s.
      values: (n, c) what the samples carry.
      known: (time s, step s) of steps found clearly elsewhere (the other node's column).
    """
    t = np.asarray(t_s, dtype=float)
    if len(t) < 4 * STEP_WINDOW:
        return t, []
    period = 1.0 / nominal_rate_hz(t)
    dt = np.diff(t)
    periods = np.maximum(1.0, np.rint(dt / period))
    off = dt - periods * period
    jitter = 1.4826 * float(np.median(np.abs(off - np.median(off))))
    least = max(MIN_CLOCK_STEP_S, 10.0 * jitter)
    candidates = np.flatnonzero(np.abs(off) > least)
    if not len(candidates) or len(candidates) > MAX_CLOCK_STEPS:
        return t, []
    sizes = _step_sizes(off, candidates)
    candidates, sizes = candidates[np.abs(sizes) > least], sizes[np.abs(sizes) > least]
    if len(candidates):  # measured again on the times without them: the steps bias the period
        regular = t - np.concatenate([[0.0], np.cumsum(np.bincount(candidates, sizes, len(dt)))])
        period = 1.0 / nominal_rate_hz(regular)
        periods = np.maximum(1.0, np.rint(dt / period))
        off = dt - periods * period
        sizes = _step_sizes(off, candidates)
    v = np.asarray(values, dtype=float).reshape(len(t), -1)
    steps: list[ClockStep] = []
    for c, size in zip(candidates.tolist(), sizes.tolist(), strict=True):  # a few steps, not samples
        readings = np.array([size + m * period for m in (0, -1, 1) if periods[c] - m >= 1])
        near = slice(max(c + 1 - STEP_FIT, 0), min(c + 1 + STEP_FIT, len(t)))
        best, other = _smoothest(t[near], v[near], c + 1 - near.start, readings)
        same = [
            j
            for j, r in enumerate(readings)
            for at, step in known
            if abs(at - t[c + 1]) < SAME_STEP_S and abs(r - step) < 1e-3
        ]
        if other is not None and same:  # the other node's column, stepped by the same clock, read it
            best, other = same[0], None
        other_s = None if other is None else float(readings[other])
        steps.append(ClockStep(c + 1, float(t[c + 1]), float(readings[best]), other_s))
    corrected = t.copy()
    for step in steps:
        corrected[step.index :] -= step.step_s
    return corrected, steps
