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

**Tips** (``TongueTip``). A tongue's tip, the lowest level at which rest becomes unstable, lies
between the grid's frequencies (a damped tongue is only ~0.01 Hz wide near its tip), so it is
not read off the grid: from every local minimum of the grid's boundary and from twice each
linear frequency and their sum, Brent's method minimises the boundary level A(f) over frequency
(A(f) by bisection on ``growth`` over [0, level_max] to 1e-7 of level_max, then interpolated
linearly in ``growth`` within the last bracket), until the frequency is known to
``TIP_FREQUENCY_TOL_HZ``. The tip is then found again with twice the steps per period (the
drive's sampling and RK4 converge with the step): the 2N tip is reported, and the difference
between the N and 2N levels is its ``level_tol_m_s2``. A tip is ``converged`` when A is no
lower at f +- TIP_FREQUENCY_TOL_HZ than at f (a minimum lies within the tolerance) at both N
and 2N, and the level's tolerance is at most ``TIP_LEVEL_REL_TOL`` of the level (or ``TIP_LEVEL_ABS_SHARE``
of level_max, for a tip at level 0).

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

from pendsim_mj.engines.linearised import LinearModes, linear_modes
from pendsim_mj.errors import ParameterError
from pendsim_mj.nonlinear.flow import RigFlow
from pendsim_mj.nonlinear.periodic import period_inputs
from pendsim_mj.rig.drives import Drive, Sine, Target
from pendsim_mj.rig.params import RigParams

PERTURBATION = 1e-7  # rad and rad/s: linear to ~1e-14 relative
UNSTABLE = 1e-9  # growth per period above which rest counts as unstable (undamped: FD noise ~1e-10)
TIP_FREQUENCY_TOL_HZ = 2e-5  # a tip's frequency is located to within this
TIP_LEVEL_REL_TOL = 1e-3  # a tip's level counts as converged when N and 2N agree to this (relative)
TIP_LEVEL_ABS_SHARE = 1e-5  # ... or to this share of level_max (a tip at level 0: no damping)
_BISECTION_REL_TOL = 1e-7  # of level_max: the boundary's bisection at one frequency


@dataclasses.dataclass(frozen=True)
class TongueTip:
    """The lowest point of one tongue's boundary, refined between the grid's frequencies.

    Attributes:
      frequency_hz: where the boundary is lowest (at 2N steps per period).
      level_m_s2: the boundary's level there, m/s^2 (at 2N).
      frequency_tol_hz: the tip lies within +- this of frequency_hz (when converged).
      level_tol_m_s2: |level at N - level at 2N| (or the bisection's tolerance if larger).
      level_n_m_s2: the level found at N steps per period.
      near: the nearest of "2 f1", "2 f2", "f1 + f2" within 0.05 Hz (the tongue it belongs to),
        else "".
      at_edge: the minimum lies at the edge of the frequency range (the tongue's tip may lie
        outside it).
      converged: a minimum within frequency_tol_hz at N and 2N (at an edge: within the range),
        and level_tol_m_s2 <= max(TIP_LEVEL_REL_TOL * level_m_s2, TIP_LEVEL_ABS_SHARE * level_max).
    """

    frequency_hz: float
    level_m_s2: float
    frequency_tol_hz: float
    level_tol_m_s2: float
    level_n_m_s2: float
    near: str
    at_edge: bool
    converged: bool


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
      tips: the refined tips of the tongues found, by ascending level (module docstring).
    """

    frequency_hz: NDArray[np.float64]
    level_m_s2: NDArray[np.float64]
    growth: NDArray[np.float64]
    boundary_m_s2: NDArray[np.float64]
    analytic_m_s2: NDArray[np.float64]
    linear_frequency_hz: NDArray[np.float64]
    steps_per_period: int
    tips: tuple[TongueTip, ...] = ()

    @property
    def lowest_tip(self) -> TongueTip | None:
        """The tip with the lowest level inside the frequency range, or None (no tongue found)."""
        return self.tips[0] if self.tips else None


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

    def boundary(
        self, frequency_hz: NDArray[np.float64], level_max_m_s2: float, *, near_m_s2: float | None = None
    ) -> NDArray[np.float64]:
        """The lowest unstable level at each frequency, (k,) m/s^2 (inf: stable up to level_max):
        bisection on ``growth`` to _BISECTION_REL_TOL of the level, then the root of growth
        interpolated linearly within the last bracket. near_m_s2: a guess; the bisection starts
        from +-5 % around it where that brackets every root, else from [0, level_max]."""
        f = np.asarray(frequency_hz, dtype=float)
        k = len(f)
        lo, hi = np.zeros(k), np.full(k, float(level_max_m_s2))
        g_lo, g_hi = np.full(k, -1.0), np.full(k, math.nan)
        if near_m_s2 is not None and 1.05 * near_m_s2 < level_max_m_s2:
            guess = np.repeat([0.95 * near_m_s2, 1.05 * near_m_s2], k)
            g = (self.growth(np.tile(f, 2), guess) - UNSTABLE).reshape(2, k)
            if np.all(g[0] <= 0) and np.all(g[1] > 0):
                lo, hi, g_lo, g_hi = guess[:k], guess[k:], g[0], g[1]
        if np.isnan(g_hi[0]):
            g_hi = self.growth(f, hi) - UNSTABLE
        floor = 1e-3 * level_max_m_s2  # a tip at level 0 (no damping): stop at 1e-10 of level_max
        while np.any(g_hi > 0) and np.max((hi - lo) / np.maximum(hi, floor)) > _BISECTION_REL_TOL:
            mid = 0.5 * (lo + hi)
            g = self.growth(f, mid) - UNSTABLE
            bad = g > 0
            hi, g_hi = np.where(bad, mid, hi), np.where(bad, g, g_hi)
            lo, g_lo = np.where(bad, lo, mid), np.where(bad, g_lo, g)
        share = np.clip(-g_lo / np.where(g_hi - g_lo > 0, g_hi - g_lo, 1.0), 0.0, 1.0)
        return np.where(g_hi > 0, lo + share * (hi - lo), np.inf)


def _minimise_boundary(
    rest: _RestMonodromy, bracket: tuple[float, float, float], level_max_m_s2: float
) -> tuple[float, float]:
    """(frequency, level) of the boundary's minimum in the bracket (low, middle, high) Hz, by
    Brent's method on A(f) (stable frequencies count as 2 level_max)."""
    from scipy.optimize import minimize_scalar  # start-up: scipy only where tips are refined

    first = rest.boundary(np.array(bracket), level_max_m_s2)
    best = [float(np.min(first))]

    def level(f: float) -> float:
        near = best[0] if math.isfinite(best[0]) else None
        a = float(rest.boundary(np.array([f]), level_max_m_s2, near_m_s2=near)[0])
        best[0] = min(best[0], a)
        return a if math.isfinite(a) else 2.0 * level_max_m_s2

    values = [float(v) if math.isfinite(v) else 2.0 * level_max_m_s2 for v in first]
    low, mid, high = bracket
    if not values[1] < min(values[0], values[2]):  # the minimum is at an end: search the whole interval
        found = minimize_scalar(level, bounds=(low, high), method="bounded",
                                options={"xatol": 0.5 * TIP_FREQUENCY_TOL_HZ})  # fmt: skip
    else:
        found = minimize_scalar(level, bracket=bracket, method="brent",
                                options={"xtol": 0.5 * TIP_FREQUENCY_TOL_HZ / mid})  # fmt: skip
    best_level, best_f = min([(float(found.fun), float(found.x)), *zip(values, bracket, strict=True)])
    return best_f, best_level


def _certified(
    rest: _RestMonodromy, f: float, a: float, bracket: tuple[float, float, float], level_max_m_s2: float
) -> tuple[float, bool]:
    """(the level at f, whether it is no higher than at f +- TIP_FREQUENCY_TOL_HZ within the
    bracket: a minimum lies within the tolerance), the three levels in one batch."""
    side = np.clip([f - TIP_FREQUENCY_TOL_HZ, f, f + TIP_FREQUENCY_TOL_HZ], bracket[0], bracket[2])
    levels = rest.boundary(side, level_max_m_s2, near_m_s2=a)
    return float(levels[1]), bool(np.all(levels >= levels[1]))


def _seeds(
    frequency_hz: NDArray[np.float64], boundary_m_s2: NDArray[np.float64], special_hz: NDArray[np.float64]
) -> list[tuple[float, float, float]]:
    """Brackets (low, middle, high) Hz around each local minimum of the grid's boundary and around
    each special frequency (2 f1, 2 f2, f1 + f2) inside the range that no bracket holds yet."""
    f, a = frequency_hz, np.where(np.isfinite(boundary_m_s2), boundary_m_s2, np.inf)
    spacing = float(np.min(np.diff(f))) if len(f) > 1 else 0.01
    out: list[tuple[float, float, float]] = []
    for k in np.flatnonzero(np.isfinite(a)):
        left, right = a[k - 1] if k > 0 else np.inf, a[k + 1] if k + 1 < len(f) else np.inf
        if a[k] <= min(left, right) and a[k] < max(left, right):  # a local minimum
            low = f[k - 1] if k > 0 else f[k]
            high = f[k + 1] if k + 1 < len(f) else f[k]
            out.append((float(low), float(f[k]), float(high)))
    for x in special_hz:
        inside = f[0] <= x <= f[-1]
        if inside and not any(low <= x <= high for low, _, high in out):
            out.append((max(f[0], x - spacing), float(x), min(f[-1], x + spacing)))
    return [b if b[0] < b[2] else (b[0] - 0.5 * spacing, b[1], b[2] + 0.5 * spacing) for b in out]


def refine_tips(
    flow: RigFlow,
    frequency_hz: NDArray[np.float64],
    boundary_m_s2: NDArray[np.float64],
    level_max_m_s2: float,
    linear_frequency_hz: NDArray[np.float64],
    steps_per_period: int,
) -> tuple[TongueTip, ...]:
    """The tips of the tongues the grid shows or the linear modes predict (module docstring), by
    ascending level; tongues that stay above level_max are left out."""
    f1, f2 = linear_frequency_hz
    special = {"2 f1": 2 * f1, "2 f2": 2 * f2, "f1 + f2": f1 + f2}
    coarse, fine = _RestMonodromy(flow, steps_per_period), _RestMonodromy(flow, 2 * steps_per_period)
    found: list[TongueTip] = []
    for bracket in _seeds(frequency_hz, boundary_m_s2, np.array(list(special.values()))):
        f_n, a_n = _minimise_boundary(coarse, bracket, level_max_m_s2)
        if not a_n < level_max_m_s2 or any(abs(t.frequency_hz - f_n) < 4 * TIP_FREQUENCY_TOL_HZ for t in found):
            continue
        a_n, ok_n = _certified(coarse, f_n, a_n, bracket, level_max_m_s2)
        # the same frequency at 2N: the level's convergence, and the minimum still within the tolerance
        a_2n, ok_2n = _certified(fine, f_n, a_n, bracket, level_max_m_s2)
        f_2n = f_n
        tol = max(abs(a_2n - a_n), _BISECTION_REL_TOL * level_max_m_s2)
        name = min(special, key=lambda k: abs(special[k] - f_2n))
        edge = min(f_2n - frequency_hz[0], frequency_hz[-1] - f_2n) < TIP_FREQUENCY_TOL_HZ
        found.append(
            TongueTip(
                frequency_hz=f_2n,
                level_m_s2=a_2n,
                frequency_tol_hz=TIP_FREQUENCY_TOL_HZ,
                level_tol_m_s2=tol,
                level_n_m_s2=a_n,
                near=name if abs(special[name] - f_2n) < 0.05 else "",
                at_edge=bool(edge),
                converged=bool(
                    ok_n and ok_2n and tol <= max(TIP_LEVEL_REL_TOL * a_2n, TIP_LEVEL_ABS_SHARE * level_max_m_s2)
                ),
            )
        )
    return tuple(sorted(found, key=lambda t: t.level_m_s2))


def tongues(
    params: RigParams,
    frequencies_hz: ArrayLike,
    level_max_m_s2: float,
    *,
    levels: int = 24,
    steps_per_period: int = 128,
    rel_tol: float = 1e-4,
    refine: bool = True,
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
      refine: find the tongues' tips between the grid's frequencies (``TongueTip``).
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
        tips = refine_tips(flow, f, boundary, level_max_m_s2, modes.frequency_hz, steps_per_period) if refine else ()
    return Tongues(
        frequency_hz=f,
        level_m_s2=grid,
        growth=growth,
        boundary_m_s2=boundary,
        analytic_m_s2=np.array([mathieu_boundary_m_s2(modes, f, m) for m in (1, 2)]),
        linear_frequency_hz=modes.frequency_hz,
        steps_per_period=steps_per_period,
        tips=tips,
    )
