"""Periodic orbits of the sine-driven rig by shooting on the MuJoCo model, with Floquet multipliers.

An orbit of period m T (T = 1/f the drive period) is a fixed point of the flow map over m periods:

    G(x0, f) = Phi_{mT}(x0; f) - x0 = 0,    x = (phi1, phi2, omega1, omega2).

Phi runs N steps per drive period at dt = T / N, so the held inputs (the drive at each step's
midpoint, ``drives.held_inputs``) are the same N values for every f: only the step changes with f.
The Jacobian columns (the monodromy matrix dPhi/dx0 and dPhi/df) are forward differences
(step FD_EPS of each unknown's scale: truncation and round-off both near 1e-7 relative), all
computed in one batched ``mujoco.rollout`` with the residual: 6 runs of m N steps, no per-step
Python loop. The Floquet multipliers are the monodromy matrix's eigenvalues: the orbit is stable
when all lie inside the unit circle.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.nonlinear.flow import RigFlow
from pendsim_mj.rig.drives import Drive, Sine, held_inputs

FD_EPS = 1e-7  # forward-difference step, relative to each unknown's scale


def drive_frequency_hz(drive: Drive) -> float:
    """The common frequency of a drive made of sines (the analyses sweep it).

    Raises:
      ParameterError: nothing is driven, a signal is not a Sine, or the sines differ in frequency.
    """
    if not drive:
        raise ParameterError("this analysis needs a drive (a sine on at least one input)")
    freqs = set()
    for target in drive.targets:
        s = drive.signal(target)
        if not isinstance(s, Sine):
            raise ParameterError(f"this analysis needs sine drives; {target.value} is a {type(s).__name__}")
        freqs.add(s.frequency_hz)
    if len(freqs) > 1:
        raise ParameterError(f"the driven sines must share one frequency (periodic forcing), got {sorted(freqs)} Hz")
    return freqs.pop()


def with_frequency(drive: Drive, frequency_hz: float) -> Drive:
    """The same sines at another frequency."""
    return Drive(
        **{
            t.value: dataclasses.replace(s, frequency_hz=frequency_hz)
            for t in drive.targets
            if isinstance(s := drive.signal(t), Sine)
        }
    )


def scaled(drive: Drive, factor: float) -> Drive:
    """The same sines with every amplitude multiplied by ``factor``."""
    return Drive(
        **{
            t.value: dataclasses.replace(s, amplitude=s.amplitude * factor)
            for t in drive.targets
            if isinstance(s := drive.signal(t), Sine)
        }
    )


def period_inputs(drive: Drive, steps_per_period: int, periods: int = 1) -> NDArray[np.float64]:
    """(periods * N, 4) held inputs over whole drive periods at N steps per period (the same for
    any frequency: the drive at (k + 1/2) / N of a period)."""
    unit = with_frequency(drive, 1.0)
    return held_inputs(unit, steps_per_period * periods, 1.0 / steps_per_period)


@dataclasses.dataclass(frozen=True)
class Orbit:
    """A periodic orbit: the states over it, its monodromy matrix and Floquet multipliers.

    Attributes:
      frequency_hz: drive frequency f. period_s: the orbit's period m / f.
      x0: (4,) state at the drive's phase 0. states: (m N + 1, 4) over one orbit period.
      monodromy: (4, 4) dPhi/dx0. multipliers: (4,) complex, by decreasing modulus.
      residual: max |Phi(x0) - x0| (rad, rad/s).
    """

    frequency_hz: float
    period_s: float
    x0: NDArray[np.float64]
    states: NDArray[np.float64]
    monodromy: NDArray[np.float64]
    multipliers: NDArray[np.complex128]
    residual: float

    @property
    def stable(self) -> bool:
        return bool(np.max(np.abs(self.multipliers)) < 1.0)

    @property
    def amplitude_rad(self) -> NDArray[np.float64]:
        """(2,) half the peak-to-peak swing of phi1, phi2 over the orbit."""
        return peak_amplitude(self.states[:, :2])

    def phase_deg(self, drive: Drive, periods: int = 1) -> NDArray[np.float64]:
        """(2,) phase of each pendulum's response at the drive frequency relative to the drive
        (its first driven sine), degrees in (-360, 0]: the lag."""
        return response_phase_deg(self.states[:-1, :2], drive, periods)


def multipliers_of(monodromy: NDArray[np.float64]) -> NDArray[np.complex128]:
    """The eigenvalues of a monodromy matrix (the Floquet multipliers), by decreasing modulus."""
    mu = np.asarray(np.linalg.eigvals(monodromy), dtype=np.complex128)
    return mu[np.argsort(-np.abs(mu))]


def peak_amplitude(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., n, k) periodic samples -> (..., k) (max - min) / 2, each extreme refined by a parabola
    through it and its neighbours (cyclically)."""
    x = np.asarray(samples)

    def refined(sign: float) -> NDArray[np.float64]:
        y = sign * x
        i = np.argmax(y, axis=-2)
        n = x.shape[-2]
        take = lambda k: np.take_along_axis(y, ((i + k) % n)[..., None, :], axis=-2)[..., 0, :]  # noqa: E731
        left, mid, right = take(-1), take(0), take(1)
        denom = left - 2 * mid + right
        with np.errstate(divide="ignore", invalid="ignore"):
            shift = np.where(denom != 0, 0.5 * (left - right) / denom, 0.0)
        return sign * (mid - 0.25 * (left - right) * shift)

    return 0.5 * (refined(1.0) - refined(-1.0))


def response_phase_deg(samples: NDArray[np.float64], drive: Drive, periods: int = 1) -> NDArray[np.float64]:
    """(n = periods N, k) samples at t = j T/N over whole drive periods -> (k,) phase of the
    component at the drive frequency relative to the drive's first sine, deg in (-360, 0]."""
    x = np.asarray(samples)
    n = x.shape[0]
    theta = 2 * math.pi * periods * np.arange(n) / n
    response = 2.0 / n * (x - x.mean(axis=0)).T @ np.exp(-1j * theta)  # x ~ Re(X e^{i w t})
    first = drive.signal(drive.targets[0])
    assert isinstance(first, Sine)
    reference = np.exp(1j * (first.phase_rad - math.pi / 2))  # sin(w t + p) = Re(e^{i(p - pi/2)} e^{i w t})
    lag = np.degrees(np.angle(response / reference))
    return np.where(lag > 0, lag - 360.0, lag)


class ForcedShooting:
    """G(x0, f) and its Jacobian for orbits of ``periods`` drive periods (module docstring).

    Args:
      flow: the rig with the drive's targets.
      drive: sines at one frequency (the frequency is the continuation parameter).
      steps_per_period: N.
      periods: m, the orbit's period in drive periods.
    """

    def __init__(self, flow: RigFlow, drive: Drive, *, steps_per_period: int = 128, periods: int = 1) -> None:
        drive_frequency_hz(drive)
        missing = set(drive.targets) - set(flow.targets)
        if missing:
            raise ParameterError(f"the flow has no actuator for {', '.join(t.value for t in missing)}")
        if steps_per_period < 16:
            raise ParameterError(f"steps_per_period must be >= 16, got {steps_per_period}")
        self.flow, self.drive, self.n, self.m = flow, drive, steps_per_period, periods
        self.inputs = period_inputs(drive, steps_per_period, periods)[None]
        self.omega_ref = 2 * math.pi * drive_frequency_hz(drive)
        # unknowns u = (x0, f): their scales for the difference steps and the arclength
        self.state_scale = np.array([1.0, 1.0, self.omega_ref, self.omega_ref])

    def dt(self, frequency_hz: NDArray[np.float64] | float) -> NDArray[np.float64]:
        return 1.0 / (np.asarray(frequency_hz) * self.n)

    def evaluate(self, x0: NDArray[np.float64], frequency_hz: float) -> tuple[Orbit, NDArray[np.float64]]:
        """The orbit data at (x0, f) and dPhi/df (4,), by one batched rollout of 6 runs."""
        if not (math.isfinite(frequency_hz) and frequency_hz > 0):
            raise ParameterError(f"drive frequency must be > 0 Hz, got {frequency_hz}")
        h = FD_EPS * self.state_scale
        df = FD_EPS * frequency_hz
        xs = np.tile(np.asarray(x0, dtype=float), (6, 1))
        xs[1:5] += np.diag(h)
        fs = np.full(6, frequency_hz)
        fs[5] += df
        out = self.flow.run(xs, self.dt(fs), self.n * self.m, self.inputs)
        end = out[:, -1, :]
        mono = (end[1:5] - end[0]).T / h
        dphi_df = (end[5] - end[0]) / df
        residual = float(np.max(np.abs(end[0] - x0)))
        orbit = Orbit(
            frequency_hz=frequency_hz,
            period_s=self.m / frequency_hz,
            x0=np.array(x0),
            states=out[0],
            monodromy=mono,
            multipliers=multipliers_of(mono),
            residual=residual,
        )
        return orbit, dphi_df

    def system(self, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], Orbit]:
        """Residual G (4,), Jacobian (4, 5) w.r.t. (x0, f), and the orbit, at u = (x0, f)."""
        orbit, dphi_df = self.evaluate(u[:4], float(u[4]))
        g = orbit.states[-1] - u[:4]
        jac = np.hstack([orbit.monodromy - np.eye(4), dphi_df[:, None]])
        return g, jac, orbit

    def steady_state(self, frequency_hz: float, x0: NDArray[np.float64], periods: int) -> NDArray[np.float64]:
        """The state after ``periods`` drive periods from x0 (an initial guess for Newton)."""
        x = np.asarray(x0, dtype=float)[None]
        chunk = max(1, min(periods, 100))
        inputs = period_inputs(self.drive, self.n, chunk)[None]
        done = 0
        while done < periods:
            k = min(chunk, periods - done)
            x = self.flow.run(x, self.dt(frequency_hz), self.n * k, inputs[:, : self.n * k])[:, -1]
            done += k
        return x[0]
