"""Backbone curves: frequency against amplitude of the nonlinear normal modes of the undamped rig.

A nonlinear normal mode (NNM) of the conservative rig is a family of periodic orbits that grows
out of a linear mode. The rig is reversible (its forces depend on the angles only), so each orbit
of the family is a brake orbit: it starts at rest, x0 = (phi1_0, phi2_0, 0, 0), and is at rest
again half a period later. Shooting on the MuJoCo model (damping set to zero) solves

    G(phi1_0, phi2_0, T) = (omega1, omega2)(T / 2) = 0

with N/2 steps of dt = T / N (the Jacobian by forward differences: 4 runs in one batched
rollout), continued in pseudo-arclength from a small amplitude on the linear mode. At every
point three checks are reported:

- the orbit closes: the periodicity residual max |x(T) - x0| over a whole period (which the
  half-period conditions do not impose; classical RK4 is not exactly time-reversible, so it is
  O(dt^4): about 1e-7 at 128 steps per period and 90 deg);
- the Floquet multipliers of the whole orbit (two are 1 for a conservative family; a pair
  off the unit circle means an unstable orbit);
- the frequency measured from a free undamped simulation started on the orbit (the standard
  10 ms step, zero crossings over several periods, fewer for unstable orbits whose error grows).

At small amplitude the backbone meets the linearised frequency (``linear.linear_modes``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines.linearised import linear_modes
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.analysis import zero_crossing_hz
from pendsim_mj.nonlinear.continuation import Point, Settings, continue_branch, newton
from pendsim_mj.nonlinear.flow import RigFlow
from pendsim_mj.nonlinear.periodic import multipliers_of, peak_amplitude
from pendsim_mj.rig.params import RigParams

FD_EPS = 1e-7
STABILITY_TOL = 1e-4  # a nontrivial multiplier this far outside the unit circle: unstable


@dataclasses.dataclass(frozen=True)
class Backbone:
    """The backbone of one mode; arrays over its P points from small to large amplitude.

    Attributes:
      mode: 1 (lower frequency) or 2.
      frequency_hz: (P,) 1 / T. amplitude_rad: (P, 2) (max - min)/2 of phi1, phi2 over the orbit.
      phi0_rad: (P, 2) the angles at the brake point (velocities zero there).
      periodicity_residual: (P,) max |x(T) - x0| over one whole period (rad, rad/s).
      multipliers: (P, 4) Floquet multipliers, by decreasing modulus. stable: (P,) whether the
        two besides the trivial pair at +1 lie on the unit circle (within STABILITY_TOL).
      free_frequency_hz: (P,) from a free undamped simulation started on the orbit.
      free_periods: (P,) how many periods that measurement spans.
      linear_frequency_hz: the linearised frequency of the mode (reference equations).
      steps_per_period: N. free_dt_s: the free simulation's step. end_reason: why it stopped.
    """

    mode: int
    frequency_hz: NDArray[np.float64]
    amplitude_rad: NDArray[np.float64]
    phi0_rad: NDArray[np.float64]
    periodicity_residual: NDArray[np.float64]
    multipliers: NDArray[np.complex128]
    stable: NDArray[np.bool_]
    free_frequency_hz: NDArray[np.float64]
    free_periods: NDArray[np.int64]
    linear_frequency_hz: float
    steps_per_period: int
    free_dt_s: float
    end_reason: str

    @property
    def free_relative_difference(self) -> NDArray[np.float64]:
        """(P,) |f_free - f| / f."""
        return np.abs(self.free_frequency_hz - self.frequency_hz) / self.frequency_hz


class _BrakeShooting:
    """G(phi0, T) = omega(T/2) and its Jacobian (module docstring)."""

    def __init__(self, flow: RigFlow, steps_per_period: int) -> None:
        if steps_per_period < 16 or steps_per_period % 2:
            raise ParameterError(f"steps_per_period must be an even number >= 16, got {steps_per_period}")
        self.flow, self.n = flow, steps_per_period

    def system(self, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], None]:
        period = float(u[2])
        if not (math.isfinite(period) and period > 0):
            raise ParameterError(f"period must be > 0 s, got {period}")
        h = FD_EPS * np.array([1.0, 1.0, period])
        xs = np.zeros((4, 4))
        xs[:, :2] = u[:2]
        xs[1, 0] += h[0]
        xs[2, 1] += h[1]
        periods = np.array([period, period, period, period + h[2]])
        out = self.flow.run(xs, periods / self.n, self.n // 2)[:, -1, 2:]
        jac = (out[1:] - out[0]).T / h
        return out[0], jac, None

    def orbit(self, phi0: NDArray[np.float64], period: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """States over one whole period (N + 1, 4) and the monodromy matrix (4, 4), by central
        differences (the trivial double multiplier 1 is a Jordan block: a difference error e
        splits it by about sqrt(e), so the monodromy needs the more accurate scheme)."""
        x0 = np.array([phi0[0], phi0[1], 0.0, 0.0])
        h = 1e-5 * np.array([1.0, 1.0, 2 * math.pi / period, 2 * math.pi / period])
        xs = np.tile(x0, (9, 1))
        xs[1:5] += np.diag(h)
        xs[5:9] -= np.diag(h)
        out = self.flow.run(xs, period / self.n, self.n)
        mono = (out[1:5, -1] - out[5:9, -1]).T / (2 * h)
        return out[0], mono


def nontrivial_multipliers(multipliers: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """(..., 4) Floquet multipliers of conservative orbits without the two nearest to +1 (the
    family's own: along the orbit and across the family)."""
    mu = np.asarray(multipliers)
    order = np.argsort(np.abs(mu - 1.0), axis=-1)
    return np.take_along_axis(mu, order[..., 2:], axis=-1)


def backbone(
    params: RigParams,
    mode: int = 1,
    *,
    max_amplitude_rad: float = math.radians(90.0),
    start_amplitude_rad: float = math.radians(0.2),
    steps_per_period: int = 128,
    settings: Settings | None = None,
    free_periods: int = 10,
    free_dt_s: float = 0.01,
    progress: Callable[[float], None] | None = None,
) -> Backbone:
    """The backbone of ``mode`` of the undamped rig (module docstring).

    Args:
      params: rig parameters; the hinge damping is set to zero.
      mode: 1 or 2 (the linear modes by ascending frequency).
      max_amplitude_rad: stop once the larger swing of the two pendulums exceeds this.
      start_amplitude_rad: the first point's swing of the pendulum the mode moves most.
      steps_per_period: N (even).
      free_periods: periods of the free simulation that measures each point's frequency.
      free_dt_s: its step.
      progress: called with the current largest amplitude (rad) after each point.
    """
    if mode not in (1, 2):
        raise ParameterError(f"mode must be 1 or 2, got {mode!r}")
    if not (0 < start_amplitude_rad < max_amplitude_rad < math.pi):
        raise ParameterError(
            f"need 0 < start_amplitude_rad < max_amplitude_rad < pi, got {start_amplitude_rad}, {max_amplitude_rad}"
        )
    undamped = params.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0)
    linear = linear_modes(undamped)
    shape = linear.shapes[:, mode - 1]
    dominant = int(np.argmax(np.abs(shape)))
    period0 = 2 * math.pi / linear.omega_rad_s[mode - 1]
    settings = settings or Settings(ds=0.05, ds_max=0.2, max_points=400)
    scale = np.array([0.2, 0.2, 0.2 * period0])
    with RigFlow(undamped) as flow:
        shooting = _BrakeShooting(flow, steps_per_period)
        u0 = np.array([*(start_amplitude_rad * shape), period0])
        start = newton(shooting.system, u0, scale=scale, fixed=dominant, max_iter=20)
        if start.tangent[dominant] < 0:
            start = dataclasses.replace(start, tangent=-start.tangent)

        def amplitude(p: Point) -> float:
            return float(np.max(np.abs(p.u[:2])))

        points, why = continue_branch(
            shooting.system,
            start,
            scale=scale,
            settings=settings,
            stop=lambda p: amplitude(p) >= max_amplitude_rad or p.u[2] <= 0,
            progress=None if progress is None else (lambda p: progress(amplitude(p))),
        )
        why = "amplitude limit" if why == "stop" else why
        u = np.array([p.u for p in points])
        orbits = [shooting.orbit(x[:2], x[2]) for x in u]
        states = np.array([o[0] for o in orbits])
        mults = np.array([multipliers_of(o[1]) for o in orbits])
        residual = np.max(np.abs(states[:, -1] - states[:, 0]), axis=1)
        # the free undamped simulation from each orbit's brake point, at the standard step
        growth = np.max(np.abs(nontrivial_multipliers(mults)), axis=1)
        unstable_growth = np.maximum(growth, 1.0 + 1e-12)
        periods = np.clip(np.floor(np.log(1e5) / np.log(unstable_growth)), 2, free_periods).astype(np.int64)
        nstep = math.ceil(float(np.max(periods * u[:, 2])) / free_dt_s) + 1
        x0 = np.zeros((len(u), 4))
        x0[:, :2] = u[:, :2]
        free = flow.run(x0, free_dt_s, nstep)
    t = np.arange(nstep + 1) * free_dt_s
    amp = peak_amplitude(states[:, :-1, :2])
    free_f = np.empty(len(u))
    for i in range(len(u)):
        k = int(np.argmax(amp[i]))
        inside = t <= periods[i] * u[i, 2] + 0.25 * u[i, 2]
        try:
            free_f[i] = zero_crossing_hz(t[inside], free[i, inside, k], hysteresis=0.05 * amp[i, k])
        except ParameterError:
            free_f[i] = math.nan
    return Backbone(
        mode=mode,
        frequency_hz=1.0 / u[:, 2],
        amplitude_rad=amp,
        phi0_rad=u[:, :2],
        periodicity_residual=residual,
        multipliers=mults,
        stable=growth < 1 + STABILITY_TOL,
        free_frequency_hz=free_f,
        free_periods=periods,
        linear_frequency_hz=float(linear.frequency_hz[mode - 1]),
        steps_per_period=steps_per_period,
        free_dt_s=free_dt_s,
        end_reason=why,
    )
