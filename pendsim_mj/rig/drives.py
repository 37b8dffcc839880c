"""Drives: what is driven on the rig, by which signal, and the input each engine applies per step.

Imports no physics engine: the MuJoCo model (``pendsim_mj.rig.model``), the planar reference
(``pendsim_mj.engines.reference``) and a compiled kernel all read the same definitions.

What can be driven (``Drive``, any combination, one signal each), in this channel order:

==========  =========  =====================================================================
channel     unit       meaning
==========  =========  =====================================================================
torque_m1   N m        a motor torque at the hinge of M1, positive about paper +z (raises phi1)
torque_m2   N m        the same at the hinge of M2
support_x   m/s^2      horizontal acceleration of the support (the frame carrying the pivot
                       axis and the fixed points 6, 7), along paper +y (MuJoCo world +x)
pivot_z     m/s^2      vertical acceleration of the support, positive upward (paper -x, MuJoCo
                       world +z): the parametric excitation
==========  =========  =====================================================================

The support is driven by its *acceleration* (what a shaker controller sets, in m/s^2): the
pendulums feel only the acceleration of the frame, never its position or velocity (Galilean
invariance), and an acceleration signal stays bounded under any stepped or chirped frequency. A
sine of displacement X at frequency f is an acceleration sine of amplitude X (2 pi f)^2.

Signals: ``Sine``, ``SteppedSine`` (frequency held for a dwell, then stepped, the phase
continuous), ``Chirp`` (linear or logarithmic sweep) and ``TimeSeries`` (samples, e.g. from a
CSV file by ``read_time_series_csv``, linearly interpolated).

**Sampling.** Each engine's RK4 step evaluates the right-hand side at four stages: k1 at the
step's start t_k, k2 and k3 at its midpoint t_k + dt/2, k4 at its end t_k + dt. Two rules give the
drive's value at the stages (``Sampling``):

- ``Sampling.STAGES`` (the planar reference and the fast engine, by default): the signal at each
  stage's own time, (u(t_k), u(t_k + dt/2), u(t_k + dt)) (``stage_inputs``): the drive is
  integrated as part of the ODE, and a driven run converges at the fourth order of RK4, as a free
  run does (tests/engines/test_drive_order.py: error ratio 16 per halving of dt against
  ``scipy.integrate.solve_ivp`` at rtol 1e-12).
- ``Sampling.HELD`` (MuJoCo: ``mujoco.rollout`` holds ``ctrl`` constant over a step, all four
  stages see one value): the signal at the step's **midpoint** t_k + dt/2 held over the step
  (``held_inputs``): the midpoint rule, second order in dt, without the half-step delay (a phase
  lag of pi f dt) that sampling at the step's start would add. For a sine the held staircase's
  fundamental has the amplitude A sin(pi f dt)/(pi f dt) (1.6e-4 low at 100 steps per period) and
  no phase error. The planar engines follow it on request (``sampling=Sampling.HELD``), and then
  equal MuJoCo to 1e-9 rad.

Stage inputs are arrays (..., nstep, NSTAGE, 4): for step k the inputs at its start, midpoint and
end (``STAGE_FRACTIONS``); held inputs (..., nstep, 4) are the special case of three equal rows
(``stages_of_held``). Quantities reported at an instant t_k (accelerations, IMU readings) use the
input at t_k: the signal there (stages), or the input held over the step that starts there (held;
the last sample repeats the last step's input) (``inputs_at_samples``).
"""

from __future__ import annotations

import csv
import dataclasses
import enum
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import ParameterError


class Target(enum.Enum):
    """A driven input; ``index`` is its channel in ``held_inputs``' last axis."""

    TORQUE_M1 = "torque_m1"
    TORQUE_M2 = "torque_m2"
    SUPPORT_X = "support_x"
    PIVOT_Z = "pivot_z"

    @property
    def index(self) -> int:
        return list(Target).index(self)

    @property
    def unit(self) -> str:
        return "N m" if self in (Target.TORQUE_M1, Target.TORQUE_M2) else "m/s^2"

    @property
    def is_support(self) -> bool:
        return self in (Target.SUPPORT_X, Target.PIVOT_Z)


NCHANNEL = len(Target)
# Column labels of held inputs (recordings, CSV): the channel name with its unit.
CHANNEL_LABELS = ("torque_m1_n_m", "torque_m2_n_m", "support_x_m_s2", "pivot_z_m_s2")


class Sampling(enum.Enum):
    """How an engine's RK4 step sees the drive (module docstring, "Sampling")."""

    STAGES = "stages"  # the signal at each stage's time: fourth order (reference, fast engine)
    HELD = "held"  # the step's midpoint value held over the step: second order (MuJoCo's ctrl)


# The stage instants of one RK4 step as fractions of the step: start (k1), midpoint (k2, k3), end (k4).
STAGE_FRACTIONS = (0.0, 0.5, 1.0)
NSTAGE = len(STAGE_FRACTIONS)


def _check_number(name: str, value: object, *, positive: bool = False, non_negative: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"{name} must be finite, got {v}")
    if positive and v <= 0:
        raise ParameterError(f"{name} must be > 0, got {v}")
    if non_negative and v < 0:
        raise ParameterError(f"{name} must be >= 0, got {v}")
    return v


@dataclasses.dataclass(frozen=True)
class Sine:
    """amplitude * sin(2 pi frequency_hz t + phase_rad); amplitude in the target's unit."""

    amplitude: float
    frequency_hz: float
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        _check_number("amplitude", self.amplitude)
        _check_number("frequency_hz", self.frequency_hz, positive=True)
        _check_number("phase_rad", self.phase_rad)


@dataclasses.dataclass(frozen=True)
class SteppedSine:
    """A sine whose frequency is held for ``dwell_s`` at each of ``frequencies_hz`` in turn (then
    stays at the last); the phase is continuous across the steps, the amplitude constant."""

    amplitude: float
    frequencies_hz: tuple[float, ...]
    dwell_s: float

    def __post_init__(self) -> None:
        _check_number("amplitude", self.amplitude)
        _check_number("dwell_s", self.dwell_s, positive=True)
        if len(self.frequencies_hz) < 1:
            raise ParameterError("frequencies_hz must hold at least one frequency")
        for f in self.frequencies_hz:
            _check_number("frequencies_hz", f, positive=True)
        object.__setattr__(self, "frequencies_hz", tuple(float(f) for f in self.frequencies_hz))

    @classmethod
    def linear(cls, amplitude: float, f0_hz: float, f1_hz: float, steps: int, dwell_s: float) -> SteppedSine:
        """``steps`` frequencies evenly spaced from f0_hz to f1_hz (either direction)."""
        if not isinstance(steps, int) or steps < 1:
            raise ParameterError(f"steps must be an integer >= 1, got {steps!r}")
        return cls(amplitude, tuple(np.linspace(f0_hz, f1_hz, steps).tolist()), dwell_s)

    @property
    def duration_s(self) -> float:
        return len(self.frequencies_hz) * self.dwell_s


CHIRP_LAWS = ("linear", "log")


@dataclasses.dataclass(frozen=True)
class Chirp:
    """A frequency sweep from f0_hz at t = 0 to f1_hz at t = duration_s (linear or logarithmic in
    frequency), continuing at f1_hz afterwards; amplitude constant, phase 0 at t = 0."""

    amplitude: float
    f0_hz: float
    f1_hz: float
    duration_s: float
    law: str = "linear"

    def __post_init__(self) -> None:
        _check_number("amplitude", self.amplitude)
        _check_number("f0_hz", self.f0_hz, positive=True)
        _check_number("f1_hz", self.f1_hz, positive=True)
        _check_number("duration_s", self.duration_s, positive=True)
        if self.law not in CHIRP_LAWS:
            raise ParameterError(f"chirp law must be one of {', '.join(CHIRP_LAWS)}, got {self.law!r}")


@dataclasses.dataclass(frozen=True)
class TimeSeries:
    """Samples (t_s[i], values[i]) of the input, linearly interpolated; a run must lie within
    [t_s[0], t_s[-1]]. ``source`` says where they came from (a file and column)."""

    t_s: tuple[float, ...]
    values: tuple[float, ...]
    source: str = ""

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=float)
        v = np.asarray(self.values, dtype=float)
        if t.ndim != 1 or v.shape != t.shape or len(t) < 2:
            raise ParameterError(f"a time series needs at least 2 (time, value) samples, got {len(t)}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            bad = int(np.flatnonzero(~(np.isfinite(t) & np.isfinite(v)))[0])
            raise ParameterError(f"time series {self.source or ''} row {bad + 1}: not a finite number".strip())
        if np.any(np.diff(t) <= 0):
            bad = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise ParameterError(
                f"time series {self.source} times must increase strictly; row {bad + 2} "
                f"({t[bad + 1]:g} s) follows {t[bad]:g} s"
            )
        object.__setattr__(self, "t_s", tuple(t.tolist()))
        object.__setattr__(self, "values", tuple(v.tolist()))


Signal = Sine | SteppedSine | Chirp | TimeSeries


@dataclasses.dataclass(frozen=True)
class Drive:
    """The inputs of a run: one optional signal per target (see the module docstring for units
    and signs). ``Drive()`` drives nothing."""

    torque_m1: Signal | None = None
    torque_m2: Signal | None = None
    support_x: Signal | None = None
    pivot_z: Signal | None = None

    def __post_init__(self) -> None:
        for target in Target:
            s = getattr(self, target.value)
            if s is not None and not isinstance(s, Signal):
                raise ParameterError(f"{target.value} must be a Sine, SteppedSine, Chirp or TimeSeries, got {s!r}")

    @property
    def targets(self) -> tuple[Target, ...]:
        """The driven targets, in channel order."""
        return tuple(t for t in Target if getattr(self, t.value) is not None)

    def signal(self, target: Target) -> Signal | None:
        """The signal driving ``target``, None where it is not driven."""
        signal: Signal | None = getattr(self, target.value)
        return signal

    def __bool__(self) -> bool:
        return bool(self.targets)

    def describe(self) -> dict[str, dict[str, object]]:
        """Each driven target's signal as plain JSON-able values (kind and fields; a time series
        as its source and sample count), with the unit."""
        out: dict[str, dict[str, object]] = {}
        for target in self.targets:
            s = self.signal(target)
            assert s is not None
            fields: dict[str, object] = {"kind": type(s).__name__, "unit": target.unit}
            if isinstance(s, TimeSeries):
                fields.update(source=s.source, samples=len(s.t_s), t0_s=s.t_s[0], t1_s=s.t_s[-1])
            else:
                fields.update({f.name: getattr(s, f.name) for f in dataclasses.fields(s)})
            out[target.value] = fields
        return out


# -- evaluation --------------------------------------------------------------------------------


def phase_rad(signal: Sine | SteppedSine | Chirp, t_s: ArrayLike) -> NDArray[np.float64]:
    """The phase theta(t) of a sinusoidal signal (value = amplitude sin theta), rad; shape of t_s.

    Closed forms (a compiled kernel can evaluate them per step):
      Sine: 2 pi f t + phase.
      SteppedSine: 2 pi [sum of f_i dwell over completed dwells + f_j (t - j dwell)].
      Chirp, linear: 2 pi (f0 t + (f1 - f0) t^2 / (2 D)) for t <= D, then + 2 pi f1 (t - D).
      Chirp, log: 2 pi f0 D (r^(t/D) - 1) / ln r with r = f1/f0, for t <= D, then + 2 pi f1 (t - D).
    """
    t = np.asarray(t_s, dtype=np.float64)
    two_pi = 2.0 * math.pi
    if isinstance(signal, Sine):
        return two_pi * signal.frequency_hz * t + signal.phase_rad
    if isinstance(signal, SteppedSine):
        f = np.asarray(signal.frequencies_hz)
        dwell = signal.dwell_s
        j = np.clip(np.floor(t / dwell).astype(int), 0, len(f) - 1)
        done = np.concatenate([[0.0], np.cumsum(f * dwell)])  # cycles completed before dwell j
        stepped: NDArray[np.float64] = two_pi * (done[j] + f[j] * (t - j * dwell))
        return stepped
    if isinstance(signal, Chirp):
        f0, f1, d = signal.f0_hz, signal.f1_hz, signal.duration_s
        tc = np.minimum(t, d)
        if signal.law == "linear" or f0 == f1:
            cycles = f0 * tc + (f1 - f0) * tc * tc / (2.0 * d)
        else:
            r = f1 / f0
            cycles = f0 * d * np.expm1(tc / d * math.log(r)) / math.log(r)
        return two_pi * (cycles + f1 * np.maximum(t - d, 0.0))
    raise ParameterError(f"phase_rad needs a sinusoidal signal, got {type(signal).__name__}")


def frequency_hz(signal: Sine | SteppedSine | Chirp, t_s: ArrayLike) -> NDArray[np.float64]:
    """Instantaneous frequency d theta / dt / (2 pi) of a sinusoidal signal, Hz; shape of t_s."""
    t = np.asarray(t_s, dtype=np.float64)
    if isinstance(signal, Sine):
        return np.full(t.shape, signal.frequency_hz)
    if isinstance(signal, SteppedSine):
        f = np.asarray(signal.frequencies_hz)
        current: NDArray[np.float64] = f[np.clip(np.floor(t / signal.dwell_s).astype(int), 0, len(f) - 1)]
        return current
    if isinstance(signal, Chirp):
        f0, f1, d = signal.f0_hz, signal.f1_hz, signal.duration_s
        x = np.clip(t / d, 0.0, 1.0)
        return f0 + (f1 - f0) * x if signal.law == "linear" else f0 * (f1 / f0) ** x
    raise ParameterError(f"frequency_hz needs a sinusoidal signal, got {type(signal).__name__}")


def signal_values(signal: Signal, t_s: ArrayLike) -> NDArray[np.float64]:
    """The signal at the times t_s (any shape), in its target's unit.

    Raises:
      ParameterError: a time series does not cover t_s.
    """
    t = np.asarray(t_s, dtype=float)
    if isinstance(signal, TimeSeries):
        ts = np.asarray(signal.t_s)
        if t.size and (t.min() < ts[0] - 1e-9 or t.max() > ts[-1] + 1e-9):
            raise ParameterError(
                f"the time series {signal.source} covers {ts[0]:g} to {ts[-1]:g} s; the run needs "
                f"{t.min():g} to {t.max():g} s (shorten --duration-s or extend the series)"
            )
        return np.asarray(np.interp(t, ts, np.asarray(signal.values)), dtype=np.float64)
    return np.asarray(signal.amplitude * np.sin(phase_rad(signal, t)), dtype=np.float64)


def highest_frequency_hz(signal: Signal) -> float | None:
    """The highest frequency a signal reaches, Hz (None for a time series: its own samples)."""
    if isinstance(signal, Sine):
        return signal.frequency_hz
    if isinstance(signal, SteppedSine):
        return max(signal.frequencies_hz)
    if isinstance(signal, Chirp):
        return max(signal.f0_hz, signal.f1_hz)
    return None


STEPS_PER_PERIOD = 10
"""The fewest steps a period of a drive's sine that a run follows: the response's error grows
with f dt (a new user's torque at 10 ms: 7 % of the drive's work off at 20 Hz, 5 steps a
period, 50 % at 49 Hz; at 10 steps 1.6 %: 10 Hz over 10 s, against 1 ms and 0.2 ms), and below 2
the sine is aliased (1000 Hz fell on its zeros and did 1e-14 J of work)."""


def check_followed(drive: Drive | None, dt_s: float) -> None:
    """Refuse a drive faster than the step can follow: fewer than ``STEPS_PER_PERIOD`` steps a
    period of its highest frequency.

    Raises:
      ParameterError: naming the target, its frequency, the steps it gets and a step that follows it.
    """
    if drive is None or not drive:
        return
    limit_hz = 1.0 / (STEPS_PER_PERIOD * dt_s)
    for target in drive.targets:
        signal = drive.signal(target)
        f = highest_frequency_hz(signal) if signal is not None else None
        if f is not None and f > limit_hz:
            raise ParameterError(
                f"the {target.value} drive reaches {f:g} Hz: a step of {dt_s:g} s gives it {1.0 / (f * dt_s):.2g} "
                f"steps a period, and a run follows a drive with {STEPS_PER_PERIOD} or more (its error grows with "
                f"f dt; fewer than 2 alias it); use a step (dt_s, --dt-s) of at most {1.0 / (20.0 * f):.2g} "
                "s (20 steps a period)"
            )


def step_midpoints_s(nstep: int, dt_s: float, t0_s: float = 0.0) -> NDArray[np.float64]:
    """(nstep,) the instants t0 + (k + 1/2) dt at which the held inputs are sampled."""
    return np.asarray(t0_s + (np.arange(nstep) + 0.5) * dt_s, dtype=np.float64)


def held_inputs(drive: Drive | None, nstep: int, dt_s: float, *, t0_s: float = 0.0) -> NDArray[np.float64]:
    """The input each engine holds over each step: (nstep, 4), channels in ``Target`` order.

    Row k is every driven signal at the step's midpoint t0 + (k + 1/2) dt (module docstring);
    undriven channels are 0.

    Raises:
      ParameterError: a time series does not cover the steps' midpoints, or a signal is faster
        than the step can follow (``check_followed``).
    """
    out = np.zeros((nstep, NCHANNEL))
    if drive is None or not drive:
        return out
    check_followed(drive, dt_s)
    t_mid = step_midpoints_s(nstep, dt_s, t0_s)
    for target in drive.targets:
        signal = drive.signal(target)
        assert signal is not None
        if isinstance(signal, TimeSeries):  # the series must cover the run: [t0, t0 + nstep dt]
            signal_values(signal, [t0_s, t0_s + nstep * dt_s])
        out[:, target.index] = signal_values(signal, t_mid)
    return out


def inputs_at_samples(held: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., nstep, 4) held inputs to (..., nstep + 1, 4) per sample: row k is the input held over
    the step that starts at t_k; the last sample repeats the last step's input."""
    return np.concatenate([held, held[..., -1:, :]], axis=-2)


def stage_inputs(drive: Drive | None, nstep: int, dt_s: float, *, t0_s: float = 0.0) -> NDArray[np.float64]:
    """The inputs at each step's RK4 stages (``Sampling.STAGES``): (nstep, NSTAGE, 4).

    Row [k, j] is every driven signal at t0 + (k + STAGE_FRACTIONS[j]) dt: the step's start,
    midpoint and end (the end of step k is the start of step k + 1, the same value); undriven
    channels are 0. The midpoints equal ``held_inputs``' values bit for bit.

    Raises:
      ParameterError: a time series does not cover [t0, t0 + nstep dt], or a signal is faster
        than the step can follow (``check_followed``).
    """
    out = np.zeros((nstep, NSTAGE, NCHANNEL))
    if drive is None or not drive:
        return out
    check_followed(drive, dt_s)
    t_half = t0_s + np.arange(2 * nstep + 1) * (0.5 * dt_s)  # (2 nstep + 1,): t0 + j dt/2
    for target in drive.targets:
        signal = drive.signal(target)
        assert signal is not None
        grid = signal_values(signal, t_half)
        out[:, 0, target.index] = grid[0:-1:2]
        out[:, 1, target.index] = grid[1::2]
        out[:, 2, target.index] = grid[2::2]
    return out


def stages_of_held(held: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., nstep, 4) held inputs as stage inputs (..., nstep, NSTAGE, 4): each step's value at
    all three stages (``Sampling.HELD``: what MuJoCo's RK4 sees)."""
    return np.repeat(np.asarray(held, dtype=np.float64)[..., None, :], NSTAGE, axis=-2)


def drive_stage_inputs(
    drives: Sequence[Drive | None], nstep: int, dt_s: float, sampling: Sampling = Sampling.STAGES
) -> NDArray[np.float64]:
    """(nbatch, nstep, NSTAGE, 4) stage inputs of several drives under ``sampling``:
    ``stage_inputs`` of each, or their ``held_inputs`` at every stage."""
    if not isinstance(sampling, Sampling):
        raise ParameterError(f"sampling must be a drives.Sampling, got {sampling!r}")
    if sampling is Sampling.HELD:
        return stages_of_held(stack_inputs(drives, nstep, dt_s))
    return np.stack([stage_inputs(d, nstep, dt_s) for d in drives])


def stage_inputs_at_samples(stages: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., nstep, NSTAGE, 4) stage inputs to (..., nstep + 1, 4) per sample: row k is the input
    at t_k, the start of step k (the last sample: the end of the last step). For held stages this
    is ``inputs_at_samples`` of the held values."""
    return np.concatenate([stages[..., 0, :], stages[..., -1:, NSTAGE - 1, :]], axis=-2)


def stage_support_motion(
    stage_accel_m_s2: NDArray[np.float64], dt_s: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position and velocity of a support driven by the stage accelerations, integrated as RK4
    integrates x'' = a(t) (Simpson's rule per step: v += dt (a0 + 4 am + a1) / 6,
    x += dt v + dt^2 (a0 + 2 am) / 6; exact for held stages), from 0 with the drift-free initial
    velocity (``support_initial_velocity``'s rule: the velocity's mean over the samples is 0).

    Args:
      stage_accel_m_s2: (..., nstep, NSTAGE, m) accelerations, m/s^2.

    Returns:
      (position (..., nstep + 1, m) in m, velocity (..., nstep + 1, m) in m/s).
    """
    a0, am, a1 = (stage_accel_m_s2[..., j, :] for j in range(NSTAGE))  # each (..., nstep, m)
    dv = dt_s * (a0 + 4.0 * am + a1) / 6.0
    v_rel = np.concatenate([np.zeros_like(dv[..., :1, :]), np.cumsum(dv, axis=-2)], axis=-2)
    v = v_rel - np.mean(v_rel, axis=-2, keepdims=True)
    dx = v[..., :-1, :] * dt_s + dt_s * dt_s * (a0 + 2.0 * am) / 6.0
    x = np.concatenate([np.zeros_like(v[..., :1, :]), np.cumsum(dx, axis=-2)], axis=-2)
    return x, v


def support_initial_velocity(held_accel_m_s2: NDArray[np.float64], dt_s: float) -> NDArray[np.float64]:
    """The support velocity at t = 0 that gives its motion no drift: the one whose velocity
    v_k = v0 + dt sum_{j<k} a_j has a zero mean over the samples k = 0..nstep.

    Args:
      held_accel_m_s2: (..., nstep, m) held support accelerations.

    Returns:
      (..., m) initial velocities, m/s. (For a sine acceleration A sin(2 pi f t) this is close
      to the sine's own -A / (2 pi f).)
    """
    v_rel = np.concatenate(
        [np.zeros_like(held_accel_m_s2[..., :1, :]), np.cumsum(held_accel_m_s2, axis=-2) * dt_s], axis=-2
    )
    v0: NDArray[np.float64] = -np.mean(v_rel, axis=-2)
    return v0


def support_motion(
    held_accel_m_s2: NDArray[np.float64], dt_s: float, v0_m_s: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position and velocity of a support that starts at 0 with velocity v0 and holds each
    acceleration over its step (exact for the piecewise-constant acceleration).

    Args:
      held_accel_m_s2: (..., nstep, m) accelerations; v0_m_s: (..., m).

    Returns:
      (position (..., nstep + 1, m) in m, velocity (..., nstep + 1, m) in m/s).
    """
    a = held_accel_m_s2
    v = np.concatenate([v0_m_s[..., None, :], v0_m_s[..., None, :] + np.cumsum(a, axis=-2) * dt_s], axis=-2)
    dx = v[..., :-1, :] * dt_s + 0.5 * a * dt_s * dt_s
    x = np.concatenate([np.zeros_like(v0_m_s)[..., None, :], np.cumsum(dx, axis=-2)], axis=-2)
    return x, v


# -- files -------------------------------------------------------------------------------------

TIME_COLUMNS = ("t_s", "time_s", "t", "time")


def read_time_series_csv(path: str | Path, column: str | None = None, *, scale: float = 1.0) -> TimeSeries:
    """A time series from a CSV file: a header row, a time column in seconds (named one of
    t_s, time_s, t, time; else the first column) and the value column ``column`` (default: the
    first other column), multiplied by ``scale``.

    Raises:
      ParameterError: the file cannot be read, has no such column, or holds a non-number, too few
        rows or times that do not increase.
    """
    path = Path(path)
    try:
        with open(path, newline="") as f:
            rows = [r for r in csv.reader(f) if r and any(c.strip() for c in r)]
    except OSError as exc:
        raise ParameterError(f"cannot read {path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise ParameterError(f"{path} is not a text CSV file") from None
    if len(rows) < 3:
        raise ParameterError(f"{path}: need a header row and at least 2 rows of (time, value), got {len(rows)} rows")
    header = [h.strip() for h in rows[0]]
    t_col = next((i for i, h in enumerate(header) if h.lower() in TIME_COLUMNS), 0)
    others = [i for i in range(len(header)) if i != t_col]
    if not others:
        raise ParameterError(f"{path}: need a time column and a value column; the header has {header}")
    if column is None:
        v_col = others[0]
    elif column in header and header.index(column) != t_col:
        v_col = header.index(column)
    else:
        allowed = ", ".join(header[i] for i in others)
        raise ParameterError(f"{path}: no column {column!r}; value columns: {allowed}")
    t, v = [], []
    for line, r in enumerate(rows[1:], start=2):
        try:
            t.append(float(r[t_col]))
            v.append(float(r[v_col]) * scale)
        except (ValueError, IndexError):
            raise ParameterError(f"{path} line {line}: expected numbers in columns {header[t_col]!r} and "
                                 f"{header[v_col]!r}, got {r!r}") from None  # fmt: skip
    return TimeSeries(tuple(t), tuple(v), source=f"{path.name}:{header[v_col]}")


def drive_from_held_inputs(t_s: ArrayLike, held: ArrayLike) -> Drive:
    """The drive that reproduces recorded held inputs exactly: for each channel that is not all
    zero, a TimeSeries through (t_k + dt/2, u_k) (the midpoint each value was sampled at), with
    the first and last values extended to the steps' outer edges.

    Args:
      t_s: (n,) start of each step, uniformly spaced, s (t_s[0] becomes t = 0).
      held: (n, 4) the inputs held over those steps (e.g. a recording's /drive topic).
    """
    t = np.asarray(t_s, dtype=float)
    u = np.asarray(held, dtype=float)
    if t.ndim != 1 or u.shape != (len(t), NCHANNEL) or len(t) < 2:
        raise ParameterError(f"need (n,) times and (n, {NCHANNEL}) inputs with n >= 2, got {t.shape}, {u.shape}")
    dt = float(np.median(np.diff(t)))
    mid = t - t[0] + 0.5 * dt
    knots = np.concatenate([[0.0], mid, [mid[-1] + 0.5 * dt]])
    signals = {}
    for target in Target:
        column = u[:, target.index]
        if np.any(column):
            values = np.concatenate([[column[0]], column, [column[-1]]])
            signals[target.value] = TimeSeries(tuple(knots), tuple(values), source=f"recorded {target.value}")
    return Drive(**signals)


def recorded_drive(t_s: ArrayLike, held: ArrayLike, start_s: float, *, until_s: float | None = None) -> Drive | None:
    """A recording's drive from ``start_s`` on: drive time 0 = ``start_s`` (the release).

    The recorded inputs are held over steps starting at t_s (a /drive topic, stamped on the
    recording's clock); they become TimeSeries through (t_k + dt/2 - start, u_k) as in
    ``drive_from_held_inputs``: zero before the recorded steps (nothing driven yet), the last
    value held after them (until ``until_s``, to cover a model run a few steps longer than the
    topic). Only the steps from about one second before the start to ``until_s`` are used.

    Args:
      t_s: (n,) start of each recorded step on the recording's clock, s (ascending).
      held: (n, 4) the inputs held over those steps, channels in ``Target`` order.
      start_s: the start (release) on the same clock, s.
      until_s: the drive must cover [0, until_s] (since the start), s; default: to the last step.

    Returns:
      The drive, or None when no channel is ever non-zero over that span.
    """
    t = np.asarray(t_s, dtype=float)
    u = np.asarray(held, dtype=float)
    if t.ndim != 1 or u.shape != (len(t), NCHANNEL) or len(t) < 2:
        raise ParameterError(f"need (n,) times and (n, {NCHANNEL}) inputs with n >= 2, got {t.shape}, {u.shape}")
    dt = float(np.median(np.diff(t)))
    mid = t - start_s + 0.5 * dt
    end = mid[-1] + 0.5 * dt if until_s is None else max(float(until_s), 0.0)
    keep = (mid >= -1.0) & (mid <= end + dt)
    if not keep.any():  # the topic ends before the start: its last value held on
        keep = np.zeros(len(t), dtype=bool)
        keep[-1] = True
    mid, u = mid[keep], u[keep]
    first, last = float(mid[0] - 0.5 * dt), float(mid[-1] + 0.5 * dt)
    knots = [mid]
    values = [u]
    if first > 0.25 * dt:  # the drive begins after the start: nothing driven before its first step
        knots = [np.array([0.0, first - 1e-6 * dt]), *knots]
        values = [np.zeros((2, NCHANNEL)), *values]
    if knots[0][0] > -0.5 * dt:
        knots = [np.array([min(first, 0.0) - 0.5 * dt]), *knots]
        values = [values[0][:1], *values]
    tail = max(last, end) + 0.5 * dt
    knots.append(np.array([tail]))
    values.append(u[-1:])
    k, v = np.concatenate(knots), np.concatenate(values)
    signals = {}
    for target in Target:
        column = v[:, target.index]
        if np.any(column):
            signals[target.value] = TimeSeries(tuple(k.tolist()), tuple(column.tolist()), f"recorded {target.value}")
    return Drive(**signals) if signals else None


def stack_inputs(drives: Sequence[Drive | None], nstep: int, dt_s: float) -> NDArray[np.float64]:
    """(nbatch, nstep, 4) held inputs of several drives (``held_inputs`` of each)."""
    return np.stack([held_inputs(d, nstep, dt_s) for d in drives])
