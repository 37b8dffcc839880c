"""The largest Lyapunov exponent of the driven (or free) rig, with a convergence test over time,
step and starting point.

Benettin's method on the MuJoCo model: a run and a companion started d0 away (scaled state norm:
angles in rad, rates divided by a reference angular frequency) are rolled out together for one
interval; the companion is then pulled back to distance d0 along the current separation, and the
stretch ln(d / d0) of each interval recorded. The first quarter of the intervals lets the
separation turn into the most-expanding direction and is left out; a run's exponent is its mean
stretch per second over the other three quarters. A stable periodic orbit gives its largest
Floquet exponent ln|mu_max| / T (< 0), a quasi-periodic or conservative regular motion 0 (the
separation grows linearly: 1.85 / duration left over), chaos a positive value.

**One run is not enough.** Where the motion is chaotic, a finite run's exponent depends on where
its trajectory wandered (near the islands of regular motion of a mixed phase space it sticks and
stretches slowly): at a 170 deg undamped release one 600 s run gives anything from 0.03 to 0.16
1/s, and the scatter of a few runs understates how far their mean may be off. So the exponent is
the mean of an **ensemble**, ``members`` runs started within ``nudge_rad`` of x0, each companion
along its own random direction (after the transient, chaotic members are independent samples of
the same motion; regular ones agree), and it is checked against everything a user could have
run instead:

- other starting points and directions: the members themselves;
- a finer step: ``max(1, members // 4)`` more runs at dt / 2 (the first starting points);
- a shorter run: the ensemble's mean over the first half of the run (its last three quarters);
- statistics: the 95 % half-width of the ensemble mean, t(0.975, K - 1) s / sqrt(K).

``uncertainty_per_s`` is the largest of: the farthest any run (at dt or dt / 2) lies from the
estimate, the first half's difference, and the 95 % half-width. The estimate is ``converged``
when that is at most max(abs_tol_per_s, rel_tol |exponent|): then every run these settings allow
agrees with it to the tolerance, and so does a longer one. Otherwise ``failed_check`` says what
to change: "step" (the runs at dt agree, those at dt / 2 do not: halve the step), "time" (the
first half disagrees: run longer) or "spread" (the runs disagree: run longer; the spread of a
run's exponent shrinks about as 1 / sqrt(duration), which gives ``needed_duration_s``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import stdtrit

from pendsim_mj.errors import ParameterError
from pendsim_mj.nonlinear.flow import RigFlow, scaled_norm
from pendsim_mj.rig.drives import Drive, held_inputs
from pendsim_mj.rig.params import RigParams

SETTLE_SHARE = 0.25  # the first quarter of the intervals: the separation turns into its direction


@dataclasses.dataclass(frozen=True)
class Lyapunov:
    """The largest Lyapunov exponent with its convergence (module docstring). Exponents in 1/s.

    Attributes:
      exponent_per_s: the ensemble mean of the members' exponents.
      uncertainty_per_s: the largest of statistics_per_s, spread_per_s and
        |time_difference_per_s|: a longer or finer run falls within exponent +- this.
      converged: uncertainty_per_s <= tolerance_per_s.
      tolerance_per_s: max(abs_tol_per_s, rel_tol |exponent|).
      statistics_per_s: 95 % half-width of the ensemble mean.
      spread_per_s: the largest |run's exponent - exponent| over every run (dt and dt / 2).
      step_difference_per_s: mean of the dt / 2 runs - exponent.
      time_difference_per_s: the ensemble's mean over the first half of the run - exponent.
      failed_check: "" (converged), "spread", "step" or "time" (module docstring).
      needed_duration_s: about the duration at which the uncertainty would meet the tolerance
        (shrinking as 1 / sqrt(duration); the current one if it does).
      member_exponents_per_s: (K,) each member's exponent at dt.
      half_step_exponents_per_s: (max(1, K // 4),) the first members' at dt / 2.
      t_s: (N,) end of each interval after the transient. running_per_s: (N,) the first member's
        running estimate (sum of its stretches / t). stretch: (N,) its ln(d/d0) per interval.
      interval_s, dt_s, transient_s: the settings. x_end: (4,) the first member's final state.
    """

    exponent_per_s: float
    uncertainty_per_s: float
    converged: bool
    tolerance_per_s: float
    statistics_per_s: float
    spread_per_s: float
    step_difference_per_s: float
    time_difference_per_s: float
    failed_check: str
    needed_duration_s: float
    member_exponents_per_s: NDArray[np.float64]
    half_step_exponents_per_s: NDArray[np.float64]
    t_s: NDArray[np.float64]
    running_per_s: NDArray[np.float64]
    stretch: NDArray[np.float64]
    interval_s: float
    dt_s: float
    transient_s: float
    x_end: NDArray[np.float64]


def _t975(samples: int) -> float:
    """Student's t, the 97.5 % quantile for the mean of ``samples`` values (95 % two-sided)."""
    return float(stdtrit(max(1, samples - 1), 0.975))


def _mean_stretch_per_s(stretch: NDArray[np.float64], interval_s: float) -> NDArray[np.float64]:
    """(k, m) stretches of k intervals -> (m,) mean per second over the last three quarters."""
    first = int(SETTLE_SHARE * len(stretch))
    return np.asarray(np.mean(stretch[first:], axis=0) / interval_s, dtype=np.float64)


class _Ensemble:
    """Benettin pairs of several members at one step: the members' states, then their companions."""

    def __init__(self, flow: RigFlow, drive: Drive | None, dt_s: float, n_interval: int) -> None:
        self.flow, self.drive, self.dt_s, self.n = flow, drive, dt_s, n_interval

    def settle(self, x: NDArray[np.float64], nstep: int, progress: Callable[[float], None] | None) -> NDArray:
        done, chunk = 0, max(self.n, 1000)
        while done < nstep:
            k = min(chunk, nstep - done)
            u = held_inputs(self.drive, k, self.dt_s, t0_s=done * self.dt_s)[None]
            x = self.flow.run(x, self.dt_s, k, u)[:, -1]
            done += k
            if progress is not None:
                progress(k * self.dt_s)
        return x

    def interval(self, pair: NDArray[np.float64], t0_s: float) -> NDArray[np.float64]:
        u = held_inputs(self.drive, self.n, self.dt_s, t0_s=t0_s)[None]
        return self.flow.run(pair, self.dt_s, self.n, u)[:, -1]


def largest_lyapunov(
    params: RigParams,
    drive: Drive | None,
    *,
    x0: ArrayLike = (0.0, 0.0, 0.0, 0.0),
    duration_s: float = 600.0,
    transient_s: float = 200.0,
    interval_s: float = 1.0,
    dt_s: float = 0.01,
    d0: float = 1e-8,
    omega_ref_rad_s: float = 2 * math.pi,
    members: int = 8,
    nudge_rad: float = 1e-5,
    abs_tol_per_s: float = 0.01,
    rel_tol: float = 0.1,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
) -> Lyapunov:
    """The largest Lyapunov exponent with its convergence test (module docstring).

    Args:
      params: rig parameters. drive: any drive (or None: the free rig).
      x0: (4,) initial state. duration_s: time over which exponents are averaged, after
        transient_s of settling. interval_s: time between renormalisations (a whole number of
        steps of dt_s; for a periodic drive, its period is a good choice).
      d0: separation of each companion (scaled norm). omega_ref_rad_s: rates are divided by it
        in the norm.
      members: runs in the ensemble (>= 2); max(1, members // 4) more run at dt / 2.
      nudge_rad: members after the first start with both angles moved by up to this (uniform).
      abs_tol_per_s, rel_tol: the tolerance max(abs_tol_per_s, rel_tol |exponent|).
      seed: the nudges and the companions' directions (np.random.default_rng(seed)).
      progress: called with simulated seconds as the runs advance: the dt ensemble, then the dt / 2
        one (2 (transient_s + duration_s) in all).
    """
    for name, value in (("duration_s", duration_s), ("interval_s", interval_s), ("dt_s", dt_s), ("d0", d0)):
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{name} must be > 0, got {value}")
    for name, value in (("transient_s", transient_s), ("nudge_rad", nudge_rad), ("abs_tol_per_s", abs_tol_per_s),
                        ("rel_tol", rel_tol)):  # fmt: skip
        if not (math.isfinite(value) and value >= 0):
            raise ParameterError(f"{name} must be >= 0, got {value}")
    if isinstance(members, bool) or not isinstance(members, int) or members < 2:
        raise ParameterError(f"members must be a whole number >= 2, got {members!r}")
    n_int = round(interval_s / dt_s)
    if n_int < 1 or abs(n_int * dt_s - interval_s) > 1e-9 * interval_s:
        raise ParameterError(f"interval_s = {interval_s} s must be a whole number of steps of dt_s = {dt_s} s")
    k_total = max(4, round(duration_s / interval_s))
    n_transient = round(transient_s / dt_s)
    rng = np.random.default_rng(seed)
    starts = np.tile(np.asarray(x0, dtype=float).reshape(4), (members, 1))
    starts[1:, :2] += nudge_rad * rng.uniform(-1.0, 1.0, (members - 1, 2))
    direction = rng.standard_normal((members, 4))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    halves = max(1, members // 4)
    with RigFlow(params, drive.targets if drive is not None else ()) as flow:
        full = _Ensemble(flow, drive, dt_s, n_int)
        half = _Ensemble(flow, drive, dt_s / 2, 2 * n_int)
        t_transient = n_transient * dt_s
        x_full = full.settle(starts, n_transient, progress)
        x_half = half.settle(starts[:halves], 2 * n_transient, progress)
        stretch, pairs = _benettin(full, x_full, direction, d0, omega_ref_rad_s, k_total, t_transient, progress)
        stretch_half, _ = _benettin(half, x_half, direction[:halves], d0, omega_ref_rad_s, k_total, t_transient,
                                    progress)  # fmt: skip
    interval = n_int * dt_s
    member_exp = _mean_stretch_per_s(stretch, interval)
    half_step_exp = _mean_stretch_per_s(stretch_half, interval)
    exponent = float(np.mean(member_exp))
    statistics = _t975(members) * float(np.std(member_exp, ddof=1)) / math.sqrt(members)
    spread_dt = float(np.max(np.abs(member_exp - exponent)))
    spread = max(spread_dt, float(np.max(np.abs(half_step_exp - exponent))))
    time_diff = float(np.mean(_mean_stretch_per_s(stretch[: k_total // 2], interval))) - exponent
    uncertainty = max(statistics, spread, abs(time_diff))
    tolerance = max(abs_tol_per_s, rel_tol * abs(exponent))
    if uncertainty <= tolerance:
        failed = ""
    elif abs(time_diff) == uncertainty:
        failed = "time"
    else:
        failed = "step" if max(spread_dt, statistics) <= tolerance else "spread"
    needed = duration_s * max(1.0, (uncertainty / tolerance) ** 2) if tolerance > 0 else math.inf
    times = np.asarray((np.arange(k_total) + 1) * interval, dtype=np.float64)
    return Lyapunov(
        exponent_per_s=exponent,
        uncertainty_per_s=uncertainty,
        converged=bool(uncertainty <= tolerance),
        tolerance_per_s=tolerance,
        statistics_per_s=statistics,
        spread_per_s=spread,
        step_difference_per_s=float(np.mean(half_step_exp)) - exponent,
        time_difference_per_s=time_diff,
        failed_check=failed,
        needed_duration_s=needed,
        member_exponents_per_s=member_exp,
        half_step_exponents_per_s=half_step_exp,
        t_s=times,
        running_per_s=np.cumsum(stretch[:, 0]) / times,
        stretch=stretch[:, 0].copy(),
        interval_s=interval,
        dt_s=dt_s,
        transient_s=n_transient * dt_s,
        x_end=pairs[0].copy(),
    )


def _benettin(
    ensemble: _Ensemble,
    x: NDArray[np.float64],
    direction: NDArray[np.float64],
    d0: float,
    omega_ref_rad_s: float,
    intervals: int,
    t0_s: float,
    progress: Callable[[float], None] | None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(intervals, m) stretches ln(d/d0) of m members started at x (m, 4) with companions d0 away
    along ``direction`` (m, 4, scaled), and the final (2 m, 4) states."""
    m = len(x)
    weights = np.array([1.0, 1.0, 1.0 / omega_ref_rad_s, 1.0 / omega_ref_rad_s])
    pair = np.vstack([x, x + d0 * direction / weights])
    stretch = np.empty((intervals, m))
    t = t0_s
    for j in range(intervals):
        pair = ensemble.interval(pair, t)
        t += ensemble.n * ensemble.dt_s
        sep = pair[m:] - pair[:m]
        d = scaled_norm(sep, omega_ref_rad_s)
        if not np.all((d > 0) & np.isfinite(d)):
            raise ParameterError("a companion run coincided with its run; raise d0")
        stretch[j] = np.log(d / d0)
        pair[m:] = pair[:m] + sep * (d0 / d)[:, None]
        if progress is not None:
            progress(ensemble.n * ensemble.dt_s)
    return stretch, pair
