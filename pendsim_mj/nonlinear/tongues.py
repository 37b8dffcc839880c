"""Instability tongues of the parametrically excited rig: where vertical pivot motion makes rest
unstable, in the plane of drive frequency and level.

The pivot accelerates vertically by a_v(t) = A sin(2 pi f t) (``drives.Target.PIVOT_Z``, m/s^2).
Rest stays a solution (every moment vanishes at phi = 0), and its stability over one drive period
is that of the linearised periodic system: the monodromy matrix of small perturbations about rest,
from 4 runs of the MuJoCo model started 1e-7 off rest along each state axis (N steps per period,
one batched ``mujoco.rollout`` for every frequency and level at once). Rest is unstable where a
Floquet multiplier leaves the unit circle: ``growth`` = max ln|mu| > 0 (per period).

The boundary at each frequency is the lowest unstable level: first on a grid of levels (which also
gives the map), then refined by bisection on ``growth`` between the last stable and the first
unstable grid level.

**The Mathieu-type limit** (``mathieu_boundary_m_s2``). Linearised,
M q'' + C q' + (K_s + G (1 + a_v / g)) q = 0 (``linear.linear_modes``: the pivot's acceleration
adds to gravity, so it scales the gravity stiffness G). In the mass-normalised modes, near
2 pi f = 2 w_i only mode i's own term resonates (to first order), and its coordinate obeys the
damped Mathieu equation eta'' + c_ii eta' + w_i^2 (1 + eps sin(W t)) eta = 0 with
W = 2 pi f, eps = A G~_ii / (g w_i^2), G~ = Phi^T G Phi, c_ii = (Phi^T C Phi)_ii. Harmonic balance
with eta = a cos(W t / 2) + b sin(W t / 2) gives the first tongue's boundary

    (eps w_i^2 / 2)^2 = (w_i^2 - W^2 / 4)^2 + (c_ii W / 2)^2,
    A_i(f) = (2 g / G~_ii) sqrt((w_i^2 - W^2 / 4)^2 + (c_ii W / 2)^2),

exact to first order in eps (the next terms are O(eps^2), e.g. Mathieu's a = 1 +- q - q^2/8).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.nonlinear.flow import RigFlow
from pendsim_mj.nonlinear.linear import LinearModes, linear_modes
from pendsim_mj.nonlinear.periodic import period_inputs
from pendsim_mj.rig.drives import Drive, Sine, Target
from pendsim_mj.rig.params import RigParams

PERTURBATION = 1e-7  # rad and rad/s: linear to ~1e-14 relative
UNSTABLE = 1e-9  # growth per period above which rest counts as unstable (undamped: FD noise ~1e-10)


@dataclasses.dataclass(frozen=True)
class Tongues:
    """Stability of rest under vertical pivot motion.

    Attributes:
      frequency_hz: (F,) drive frequencies. level_m_s2: (L,) grid of acceleration amplitudes.
      growth: (L, F) max ln|Floquet multiplier| of rest per drive period (> 0: unstable).
      boundary_m_s2: (F,) the lowest level at which rest is unstable (NaN: none up to the
        grid's top).
      analytic_m_s2: (2, F) the Mathieu-type first-order boundaries of the principal tongues of
        modes 1 and 2 (module docstring).
      linear_frequency_hz: (2,) the linear modes' frequencies (the principal tongues grow from
        twice these).
      steps_per_period: N.
    """

    frequency_hz: NDArray[np.float64]
    level_m_s2: NDArray[np.float64]
    growth: NDArray[np.float64]
    boundary_m_s2: NDArray[np.float64]
    analytic_m_s2: NDArray[np.float64]
    linear_frequency_hz: NDArray[np.float64]
    steps_per_period: int


def mathieu_boundary_m_s2(modes: LinearModes, frequency_hz: ArrayLike, mode: int) -> NDArray[np.float64]:
    """The first-order boundary level A_i(f) of mode i's principal tongue (module docstring), m/s^2."""
    if mode not in (1, 2):
        raise ParameterError(f"mode must be 1 or 2, got {mode!r}")
    i = mode - 1
    w = modes.omega_rad_s[i]
    g_tilde = modes.modal(modes.gravity_stiffness_n_m)[i, i]
    c = modes.modal(modes.damping_n_m_s)[i, i]
    big_w = 2 * math.pi * np.asarray(frequency_hz, dtype=float)
    return 2.0 * modes.gravity_m_s2 / g_tilde * np.sqrt((w * w - big_w * big_w / 4) ** 2 + (c * big_w / 2) ** 2)


class _RestMonodromy:
    def __init__(self, flow: RigFlow, steps_per_period: int) -> None:
        self.flow, self.n = flow, steps_per_period
        self.unit = period_inputs(Drive(pivot_z=Sine(1.0, 1.0)), steps_per_period)  # (N, 4) for A = 1

    def growth(self, frequency_hz: NDArray[np.float64], level_m_s2: NDArray[np.float64]) -> NDArray[np.float64]:
        """max ln|mu| per period for each (f, A) pair, (k,)."""
        f = np.repeat(np.asarray(frequency_hz, dtype=float), 4)
        a = np.repeat(np.asarray(level_m_s2, dtype=float), 4)
        x0 = np.tile(PERTURBATION * np.eye(4), (len(frequency_hz), 1))
        inputs = self.unit[None] * a[:, None, None]
        end = self.flow.run(x0, 1.0 / (f * self.n), self.n, inputs)[:, -1]
        mono = end.reshape(-1, 4, 4).transpose(0, 2, 1) / PERTURBATION  # columns: the perturbed axes
        mu = np.linalg.eigvals(mono)
        return np.log(np.max(np.abs(mu), axis=1))


def tongues(
    params: RigParams,
    frequencies_hz: ArrayLike,
    level_max_m_s2: float,
    *,
    levels: int = 24,
    steps_per_period: int = 128,
    rel_tol: float = 1e-4,
    progress: Callable[[int], None] | None = None,
) -> Tongues:
    """Map the instability of rest over (frequency, level) and find the lowest unstable level at
    each frequency (module docstring).

    Args:
      params: rig parameters (with damping: the tongues then start above a threshold level).
      frequencies_hz: (F,) drive frequencies, Hz.
      level_max_m_s2: top of the level grid, m/s^2 (acceleration amplitude of the pivot).
      levels: grid levels (evenly spaced from level_max / levels up to level_max).
      steps_per_period: N.
      rel_tol: the boundary's bisection stops within rel_tol * level_max_m_s2.
      progress: called with 1 per grid level and per bisection round.
    """
    f = np.asarray(frequencies_hz, dtype=float)
    if f.ndim != 1 or len(f) < 1 or np.any(f <= 0) or not np.all(np.isfinite(f)):
        raise ParameterError("frequencies_hz must be positive, finite numbers")
    if not (math.isfinite(level_max_m_s2) and level_max_m_s2 > 0):
        raise ParameterError(f"level_max_m_s2 must be > 0, got {level_max_m_s2}")
    if levels < 2:
        raise ParameterError(f"levels must be >= 2, got {levels}")
    grid = np.linspace(level_max_m_s2 / levels, level_max_m_s2, levels)
    growth = np.empty((levels, len(f)))
    with RigFlow(params, (Target.PIVOT_Z,)) as flow:
        rest = _RestMonodromy(flow, steps_per_period)
        for k, level in enumerate(grid):
            growth[k] = rest.growth(f, np.full(len(f), level))
            if progress is not None:
                progress(1)
        unstable = growth > UNSTABLE
        first = np.where(unstable.any(axis=0), np.argmax(unstable, axis=0), -1)
        has = first >= 0
        lo = np.where(first > 0, grid[np.maximum(first - 1, 0)], 0.0)
        hi = np.where(has, grid[np.maximum(first, 0)], np.nan)
        idx = np.flatnonzero(has)
        lo, hi = lo[idx], hi[idx]
        while len(idx) and np.max(hi - lo) > rel_tol * level_max_m_s2:
            mid = 0.5 * (lo + hi)
            bad = rest.growth(f[idx], mid) > UNSTABLE
            hi = np.where(bad, mid, hi)
            lo = np.where(bad, lo, mid)
            if progress is not None:
                progress(1)
    boundary = np.full(len(f), np.nan)
    boundary[idx] = 0.5 * (lo + hi)
    modes = linear_modes(params)
    return Tongues(
        frequency_hz=f,
        level_m_s2=grid,
        growth=growth,
        boundary_m_s2=boundary,
        analytic_m_s2=np.array([mathieu_boundary_m_s2(modes, f, m) for m in (1, 2)]),
        linear_frequency_hz=modes.frequency_hz,
        steps_per_period=steps_per_period,
    )
