"""Frequency-response curves of the sine-driven rig: stepped sine and continuation.

(a) **Stepped sine** (``stepped_sine``): the drive frequency steps through a list, up and down
    (two runs in one batch), each step a whole number of drive periods at N steps per period; the
    state carries over from one step to the next, so the sweep stays on the branch it is on and
    jumps where that branch ends (hysteresis). Each step runs in chunks of ``chunk_periods``
    until the amplitude over the last period changes by less than ``settle_tol`` (relative)
    from one chunk to the next, or ``max_periods``; then amplitude ((max - min)/2 of phi over
    the last period), phase of the response at the drive frequency, and the phase locking of the
    two pendulums over the last ``measure_periods`` are read.
(b) **Continuation** (``continue_response``): periodic orbits of the forced, damped rig by
    shooting on the MuJoCo model (``periodic.ForcedShooting``) with pseudo-arclength
    continuation in the drive frequency, Floquet multipliers at every point, stability, and
    the bifurcations between points (``detect_bifurcations``): folds (the frequency turns
    back; a real multiplier passes +1), period doubling (a real multiplier passes -1),
    Neimark-Sacker (a complex pair leaves or enters the unit circle) and branch points (a real
    multiplier passes +1 where the frequency does not turn back).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.nonlinear.continuation import Point, Settings, continue_branch, newton, turning_point
from pendsim_mj.nonlinear.flow import RigFlow, scaled_norm
from pendsim_mj.nonlinear.periodic import (
    ForcedShooting,
    Orbit,
    drive_frequency_hz,
    peak_amplitude,
    period_inputs,
    response_phase_deg,
)
from pendsim_mj.nonlinear.sync import phase_locking
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import RigParams

BIFURCATION_KINDS = ("fold", "period_doubling", "neimark_sacker", "branch_point")


# -- (a) stepped sine --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SteppedSweep:
    """One stepped-sine sweep; arrays over its F frequency steps, in the order run.

    Attributes:
      direction: "up" or "down".
      frequency_hz: (F,) drive frequency of each step.
      amplitude_rad: (F, 2) steady amplitude of phi1, phi2 ((max - min)/2 over the last period).
      phase_deg: (F, 2) phase of each pendulum's response at the drive frequency relative to the
        drive, deg in (-360, 0].
      periods: (F,) drive periods run at each step.
      settled: (F,) whether the amplitude settled to settle_tol before max_periods.
      periodicity_residual: (F,) |x(t) - x(t - T)| at the end of each step (scaled norm, rad):
        0 for a periodic (period-1) steady state.
      locking_index: (F,) 1:1 phase-locking index of phi1 and phi2 over the measuring window
        (of sin(phi): one cycle per swing, or per turn of a pendulum driven over the top).
      frequency_ratio: (F,) mean frequency of phi1 over that of phi2 in the window.
    """

    direction: str
    frequency_hz: NDArray[np.float64]
    amplitude_rad: NDArray[np.float64]
    phase_deg: NDArray[np.float64]
    periods: NDArray[np.int64]
    settled: NDArray[np.bool_]
    periodicity_residual: NDArray[np.float64]
    locking_index: NDArray[np.float64]
    frequency_ratio: NDArray[np.float64]


def stepped_sine(
    params: RigParams,
    drive: Drive,
    frequencies_hz: ArrayLike,
    *,
    steps_per_period: int = 128,
    chunk_periods: int = 10,
    min_periods: int = 20,
    max_periods: int = 400,
    settle_tol: float = 1e-4,
    measure_periods: int = 10,
    x0: ArrayLike = (0.0, 0.0, 0.0, 0.0),
    directions: Sequence[str] = ("up", "down"),
    progress: Callable[[int], None] | None = None,
) -> tuple[SteppedSweep, ...]:
    """Stepped-sine sweeps (module docstring), one per direction, run together as one batch.

    Args:
      params: rig parameters.
      drive: sines at one frequency (their amplitudes and phases are kept; the frequency is
        stepped).
      frequencies_hz: (F,) the steps, ascending; "down" runs them in reverse.
      steps_per_period: N.
      chunk_periods, min_periods, max_periods, settle_tol: settling (module docstring).
      measure_periods: window for the phase locking (and at least the last period).
      x0: initial state of every sweep (rad, rad/s).
      directions: any of "up", "down".
      progress: called with 1 after each frequency step.

    Returns:
      One SteppedSweep per direction.
    """
    drive_frequency_hz(drive)
    f_up = np.asarray(frequencies_hz, dtype=float)
    if f_up.ndim != 1 or len(f_up) < 1 or np.any(f_up <= 0) or np.any(np.diff(f_up) <= 0):
        raise ParameterError("frequencies_hz must be positive and ascending")
    if not set(directions) <= {"up", "down"} or not directions:
        raise ParameterError(f"directions must be 'up' and/or 'down', got {directions!r}")
    if measure_periods > min_periods or chunk_periods < 1 or max_periods < min_periods:
        raise ParameterError("need 1 <= chunk_periods, measure_periods <= min_periods <= max_periods")
    n = steps_per_period
    order = {"up": f_up, "down": f_up[::-1]}
    nb = len(directions)
    x = np.tile(np.asarray(x0, dtype=float), (nb, 1))
    nf = len(f_up)
    amp = np.zeros((nb, nf, 2))
    phase = np.zeros((nb, nf, 2))
    periods = np.zeros((nb, nf), dtype=np.int64)
    settled = np.zeros((nb, nf), dtype=bool)
    resid = np.zeros((nb, nf))
    plv = np.zeros((nb, nf))
    ratio = np.zeros((nb, nf))
    chunk_inputs = period_inputs(drive, n, chunk_periods)[None]
    with RigFlow(params, drive.targets) as flow:
        for i in range(nf):
            f = np.array([order[d][i] for d in directions])
            dt = 1.0 / (f * n)
            last_amp = np.full((nb, 2), np.nan)
            window: list[NDArray[np.float64]] = []
            run = 0
            done = np.zeros(nb, dtype=bool)
            while True:
                out = flow.run(x, dt, n * chunk_periods, chunk_inputs)
                x = out[:, -1].copy()
                run += chunk_periods
                window = [*window, out[:, :-1]][-(measure_periods // chunk_periods + 2) :]
                a = peak_amplitude(out[:, -n - 1 : -1, :2])
                change = np.max(np.abs(a - last_amp) / np.maximum(np.abs(a), 1e-12), axis=1)
                done = done | ((change < settle_tol) & (run >= min_periods))
                last_amp = a
                if np.all(done) or run >= max_periods:
                    break
            states = np.concatenate(window, axis=1)[:, -n * measure_periods :]  # (nb, measure N, 4)
            for b, d in enumerate(directions):
                amp[b, i] = last_amp[b]
                phase[b, i] = response_phase_deg(out[b, -n - 1 : -1, :2], drive)
                periods[b, i] = run
                settled[b, i] = done[b]
                resid[b, i] = float(scaled_norm(out[b, -1] - out[b, -n - 1], 2 * math.pi * f[b]))
                t = np.arange(states.shape[1]) * dt[b]
                # sin(phi): the same zero crossings as phi, and one cycle per turn of a pendulum
                # driven over the top
                lock = phase_locking(t, np.sin(states[b, :, 0]), np.sin(states[b, :, 1]))
                plv[b, i], ratio[b, i] = lock.index, lock.frequency_ratio
                del d
            if progress is not None:
                progress(1)
    return tuple(
        SteppedSweep(
            direction=d,
            frequency_hz=order[d].copy(),
            amplitude_rad=amp[b],
            phase_deg=phase[b],
            periods=periods[b],
            settled=settled[b],
            periodicity_residual=resid[b],
            locking_index=plv[b],
            frequency_ratio=ratio[b],
        )
        for b, d in enumerate(directions)
    )


# -- (b) continuation --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Bifurcation:
    """A bifurcation located between branch points ``index`` and ``index + 1``.

    kind: "fold", "period_doubling", "neimark_sacker" or "branch_point". frequency_hz and
    amplitude_rad (2,): where. A fold found by ``continue_response`` is refined to the turning
    point of the frequency (``continuation.turning_point``: a converged orbit there, ``refined``);
    every other bifurcation is interpolated between the two points. frequency_tol_hz and
    amplitude_tol_rad (2,): the bifurcation lies within these of the values given (refined: the
    last bracket's width; interpolated: the distance between the two points). multiplier: the
    Floquet multiplier that crosses the unit circle (at point index + 1).
    """

    kind: str
    index: int
    frequency_hz: float
    amplitude_rad: NDArray[np.float64]
    multiplier: complex
    frequency_tol_hz: float = math.nan
    amplitude_tol_rad: NDArray[np.float64] = dataclasses.field(default_factory=lambda: np.full(2, math.nan))
    refined: bool = False


@dataclasses.dataclass(frozen=True)
class ResponseBranch:
    """A branch of periodic orbits; arrays over its P points in continuation order.

    Attributes:
      frequency_hz: (P,). amplitude_rad: (P, 2). phase_deg: (P, 2) as in SteppedSweep.
      x0: (P, 4) orbit state at the drive's phase 0. multipliers: (P, 4) Floquet multipliers,
      by decreasing modulus. stable: (P,). residual: (P,) max |Phi(x0) - x0|.
      bifurcations: where the stability changes. end_reason: why the continuation stopped.
      periods: the orbits' period in drive periods. steps_per_period: N.
    """

    frequency_hz: NDArray[np.float64]
    amplitude_rad: NDArray[np.float64]
    phase_deg: NDArray[np.float64]
    x0: NDArray[np.float64]
    multipliers: NDArray[np.complex128]
    stable: NDArray[np.bool_]
    residual: NDArray[np.float64]
    bifurcations: tuple[Bifurcation, ...]
    end_reason: str
    periods: int
    steps_per_period: int

    def folds(self) -> list[Bifurcation]:
        return [b for b in self.bifurcations if b.kind == "fold"]


def _interpolate(a: float, b: float) -> float:
    """Where a linear function with values a at 0 and b at 1 crosses 0, clipped to [0, 1]."""
    return float(np.clip(a / (a - b), 0.0, 1.0)) if a != b else 0.5


def detect_bifurcations(
    frequency_hz: NDArray[np.float64],
    amplitude_rad: NDArray[np.float64],
    multipliers: NDArray[np.complex128],
    tangent_f: NDArray[np.float64],
) -> tuple[Bifurcation, ...]:
    """Bifurcations between consecutive points of a branch (module docstring).

    Args:
      frequency_hz: (P,). amplitude_rad: (P, 2). multipliers: (P, k).
      tangent_f: (P,) the frequency component of the branch tangent (its sign change is a fold).
    """
    out: list[Bifurcation] = []
    real_tol = 1e-7

    def at(i: int, s: float) -> tuple[float, NDArray[np.float64]]:
        return (
            float(frequency_hz[i] + s * (frequency_hz[i + 1] - frequency_hz[i])),
            amplitude_rad[i] + s * (amplitude_rad[i + 1] - amplitude_rad[i]),
        )

    def found(kind: str, i: int, f: float, a: NDArray[np.float64], mu: complex) -> Bifurcation:
        width_f = float(abs(frequency_hz[i + 1] - frequency_hz[i]))
        width_a = np.abs(amplitude_rad[i + 1] - amplitude_rad[i])
        return Bifurcation(kind, i, f, a, mu, frequency_tol_hz=width_f, amplitude_tol_rad=width_a)

    for i in range(len(frequency_hz) - 1):
        mu0, mu1 = multipliers[i], multipliers[i + 1]
        minus_one = (np.prod(mu0 + 1).real, np.prod(mu1 + 1).real)
        plus_one = (np.prod(mu0 - 1).real, np.prod(mu1 - 1).real)
        complex_out = [int(np.sum((np.abs(mu.imag) > real_tol) & (np.abs(mu) > 1))) for mu in (mu0, mu1)]
        if np.sign(tangent_f[i]) != np.sign(tangent_f[i + 1]):
            # the turning point of f: the vertex of a parabola through three points, by arclength
            j = i if i + 2 < len(frequency_hz) else i - 1
            s = _vertex(frequency_hz[j : j + 3]) if j >= 0 else 0.5
            lo = np.clip(s + (j - i), 0.0, 1.0)
            f, a = at(i, lo)
            if len(frequency_hz) >= 3 and j >= 0:
                f = float(_parabola_value(frequency_hz[j : j + 3], s))
            crossing = mu1[np.argmin(np.abs(mu1 - 1))]
            out.append(found("fold", i, f, a, complex(crossing)))
        elif np.sign(plus_one[0]) != np.sign(plus_one[1]):
            f, a = at(i, _interpolate(*plus_one))
            out.append(found("branch_point", i, f, a, complex(mu1[np.argmin(np.abs(mu1 - 1))])))
        if np.sign(minus_one[0]) != np.sign(minus_one[1]):
            f, a = at(i, _interpolate(*minus_one))
            out.append(found("period_doubling", i, f, a, complex(mu1[np.argmin(np.abs(mu1 + 1))])))
        if complex_out[0] != complex_out[1]:
            c0 = np.max(np.abs(mu0[np.abs(mu0.imag) > real_tol]), initial=0.0) - 1
            c1 = np.max(np.abs(mu1[np.abs(mu1.imag) > real_tol]), initial=0.0) - 1
            f, a = at(i, _interpolate(c0, c1))
            pair = mu1[np.abs(mu1.imag) > real_tol]
            mult = complex(pair[np.argmax(np.abs(pair))]) if len(pair) else complex(mu1[0])
            out.append(found("neimark_sacker", i, f, a, mult))
    return tuple(out)


def _vertex(y: NDArray[np.float64]) -> float:
    """x of the extremum of the parabola through (0, y0), (1, y1), (2, y2)."""
    denom = y[0] - 2 * y[1] + y[2]
    return float(np.clip(0.5 + (y[0] - y[2]) / (2 * denom), 0.0, 2.0)) if denom != 0 else 1.0


def _parabola_value(y: NDArray[np.float64], s: float) -> float:
    a = 0.5 * (y[0] - 2 * y[1] + y[2])
    b = 0.5 * (y[2] - y[0])
    return float(y[1] + b * (s - 1) + a * (s - 1) ** 2)


def _branch(points: list[Point], drive: Drive, shooting: ForcedShooting, end_reason: str) -> ResponseBranch:
    orbits: list[Orbit] = [p.extra for p in points]
    freq = np.array([o.frequency_hz for o in orbits])
    amp = np.array([o.amplitude_rad for o in orbits])
    mult = np.array([o.multipliers for o in orbits])
    tangent_f = np.array([p.tangent[4] for p in points])
    return ResponseBranch(
        frequency_hz=freq,
        amplitude_rad=amp,
        phase_deg=np.array([o.phase_deg(drive, shooting.m) for o in orbits]),
        x0=np.array([o.x0 for o in orbits]),
        multipliers=mult,
        stable=np.array([o.stable for o in orbits]),
        residual=np.array([o.residual for o in orbits]),
        bifurcations=detect_bifurcations(freq, amp, mult, tangent_f),
        end_reason=end_reason,
        periods=shooting.m,
        steps_per_period=shooting.n,
    )


def continue_response(
    params: RigParams,
    drive: Drive,
    f_start_hz: float,
    f_end_hz: float,
    *,
    steps_per_period: int = 128,
    transient_periods: int = 300,
    x0: ArrayLike = (0.0, 0.0, 0.0, 0.0),
    amplitude_scale_rad: float = 0.2,
    settings: Settings | None = None,
    max_amplitude_rad: float = math.radians(150.0),
    progress: Callable[[Point], None] | None = None,
) -> ResponseBranch:
    """Continue the period-1 orbits from f_start_hz toward f_end_hz (module docstring).

    The first orbit is the state after ``transient_periods`` at f_start_hz from x0, corrected
    by Newton at fixed frequency; the branch then follows its arclength (through folds) until the
    frequency leaves [min, max] of the two ends, the swing exceeds max_amplitude_rad, or
    ``settings.max_points``.

    Args:
      amplitude_scale_rad: the angle that weighs as much as the whole frequency range in the
        arclength (with rates divided by 2 pi f).
    """
    lo, hi = sorted((float(f_start_hz), float(f_end_hz)))
    if not (lo > 0 and hi > lo):
        raise ParameterError(f"need 0 < f_start_hz != f_end_hz, got {f_start_hz}, {f_end_hz}")
    settings = settings or Settings(ds=0.05, ds_max=0.15, max_points=600)
    drive_frequency_hz(drive)
    with RigFlow(params, drive.targets) as flow:
        shooting = ForcedShooting(flow, drive, steps_per_period=steps_per_period)
        omega = 2 * math.pi * 0.5 * (lo + hi)
        a = amplitude_scale_rad
        scale = np.array([a, a, a * omega, a * omega, hi - lo])
        guess = shooting.steady_state(f_start_hz, np.asarray(x0, dtype=float), transient_periods)
        start = newton(shooting.system, np.append(guess, f_start_hz), scale=scale, fixed=4, max_iter=30)
        tangent = start.tangent if start.tangent[4] * (f_end_hz - f_start_hz) > 0 else -start.tangent
        start = dataclasses.replace(start, tangent=tangent)
        margin = 1e-9 * (hi - lo)

        def stop(p: Point) -> bool:
            f = p.u[4]
            return bool(f < lo - margin or f > hi + margin or np.max(np.abs(p.extra.states[:, :2])) > max_amplitude_rad)

        points, why = continue_branch(
            shooting.system, start, scale=scale, settings=settings, stop=stop, progress=progress
        )
        if why == "stop" and len(points) > 1:
            last = points[-1]
            f = float(np.clip(last.u[4], lo, hi))
            if f != last.u[4]:  # end exactly on the range's edge
                prev = points[-2]
                s = (f - prev.u[4]) / (last.u[4] - prev.u[4])
                try:
                    end = newton(
                        shooting.system,
                        prev.u + s * (last.u - prev.u),
                        scale=scale,
                        fixed=4,
                        tol=settings.newton_tol,
                    )
                    end = dataclasses.replace(end, tangent=last.tangent)
                    points[-1] = end
                except ParameterError:
                    pass
            why = (
                "end of the frequency range"
                if np.max(np.abs(last.extra.states[:, :2])) <= max_amplitude_rad
                else ("amplitude limit")
            )
        branch = _branch(points, drive, shooting, why)
        refined = tuple(_refined_fold(b, points, shooting, scale, settings) if b.kind == "fold" else b
                        for b in branch.bifurcations)  # fmt: skip
        return dataclasses.replace(branch, bifurcations=refined)


def _refined_fold(
    fold: Bifurcation, points: list[Point], shooting: ForcedShooting, scale: NDArray[np.float64], settings: Settings
) -> Bifurcation:
    """The fold at the turning point of the frequency between its two branch points (a converged
    orbit there), or the interpolated fold unchanged where the refinement fails."""
    try:
        turn = turning_point(shooting.system, points[fold.index], points[fold.index + 1], scale=scale,
                             component=4, settings=settings)  # fmt: skip
    except (ParameterError, SimulationDiverged):
        return fold
    orbit, (lo, hi) = turn.point.extra, turn.bracket
    return dataclasses.replace(
        fold,
        frequency_hz=float(turn.point.u[4]),
        amplitude_rad=orbit.amplitude_rad,
        frequency_tol_hz=float(abs(hi.u[4] - lo.u[4])),
        amplitude_tol_rad=np.abs(hi.extra.amplitude_rad - lo.extra.amplitude_rad),
        refined=True,
    )


def orbit_at(
    params: RigParams, drive: Drive, frequency_hz: float, x_guess: ArrayLike, *, steps_per_period: int = 128
) -> Orbit:
    """The periodic orbit at a given frequency by Newton from x_guess (e.g. a branch's
    interpolated point or the end of a stepped-sine step).

    Raises:
      ParameterError: Newton did not converge.
    """
    with RigFlow(params, drive.targets) as flow:
        shooting = ForcedShooting(flow, drive, steps_per_period=steps_per_period)
        omega = 2 * math.pi * frequency_hz
        scale = np.array([0.2, 0.2, 0.2 * omega, 0.2 * omega, frequency_hz])
        p = newton(shooting.system, np.append(np.asarray(x_guess, float), frequency_hz), scale=scale, fixed=4)
        return p.extra


def branch_values_at(branch: ResponseBranch, frequency_hz: float, *, stable_only: bool = True) -> list[int]:
    """Indices i of the branch segments [i, i + 1] that contain ``frequency_hz`` (both points
    stable if ``stable_only``)."""
    f = branch.frequency_hz
    out = []
    for i in range(len(f) - 1):
        inside = min(f[i], f[i + 1]) <= frequency_hz <= max(f[i], f[i + 1]) and f[i] != f[i + 1]
        if inside and (not stable_only or (branch.stable[i] and branch.stable[i + 1])):
            out.append(i)
    return out


@dataclasses.dataclass(frozen=True)
class Agreement:
    """Stepped sine against continuation at each stepped frequency of one sweep: the branch's
    amplitude of phi1 at exactly that frequency (Newton from the nearest stable segment; NaN if
    no stable segment covers it) and the relative difference |stepped - branch| / branch."""

    frequency_hz: NDArray[np.float64]
    stepped_rad: NDArray[np.float64]
    branch_rad: NDArray[np.float64]
    relative_difference: NDArray[np.float64]

    @property
    def max_relative_difference(self) -> float:
        d = self.relative_difference[np.isfinite(self.relative_difference)]
        return float(np.max(d)) if len(d) else math.nan


def compare_with_branch(
    params: RigParams, drive: Drive, sweep: SteppedSweep, branch: ResponseBranch, *, pendulum: int = 0
) -> Agreement:
    """How closely a stepped-sine sweep follows the stable parts of a continued branch."""
    branch_amp = np.full(len(sweep.frequency_hz), np.nan)
    for k, f in enumerate(sweep.frequency_hz):
        segments = branch_values_at(branch, f)
        if not segments:
            continue
        candidates = []
        for i in segments:
            s = (f - branch.frequency_hz[i]) / (branch.frequency_hz[i + 1] - branch.frequency_hz[i])
            guess = branch.x0[i] + s * (branch.x0[i + 1] - branch.x0[i])
            try:
                orbit = orbit_at(params, drive, float(f), guess, steps_per_period=branch.steps_per_period)
            except ParameterError:
                continue
            candidates.append(orbit.amplitude_rad[pendulum])
        if candidates:  # the stable branch the sweep is on: the nearest one
            measured = sweep.amplitude_rad[k, pendulum]
            branch_amp[k] = min(candidates, key=lambda c: abs(c - measured))
    with np.errstate(invalid="ignore"):
        rel = np.abs(sweep.amplitude_rad[:, pendulum] - branch_amp) / branch_amp
    return Agreement(sweep.frequency_hz.copy(), sweep.amplitude_rad[:, pendulum].copy(), branch_amp, rel)
