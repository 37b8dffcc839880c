"""The largest Lyapunov exponent of the driven (or free) rig, with its convergence.

Benettin's method on the MuJoCo model: a run and a companion started d0 away (scaled state norm:
angles in rad, rates divided by a reference angular frequency) are rolled out together for one
interval; the companion is then pulled back to distance d0 along the current separation, and
ln(d / d0) accumulated. After K intervals the estimate is

    lambda_K = sum_j ln(d_j / d0) / (K interval),   1/s,

and ``running_per_s`` holds lambda_k for every k (the convergence curve). The cumulative sum
S_k = lambda t_k + (a bounded term: the initial direction, the rotation of a complex pair), so the
running mean converges as 1/t; the reported exponent is the slope of a least-squares line through
S_k over the second half of the run, which removes the bounded offset. A stable periodic orbit
gives its largest Floquet exponent ln|mu_max| / T (< 0), a quasi-periodic or conservative motion 0,
chaos a positive value. The spread of lambda_k over the last quarter of the run is reported as a
rough uncertainty.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.nonlinear.flow import RigFlow, scaled_norm
from pendsim_mj.rig.drives import Drive, held_inputs
from pendsim_mj.rig.params import RigParams


@dataclasses.dataclass(frozen=True)
class Lyapunov:
    """exponent_per_s: the estimate (slope of the cumulative sum over the second half).
    spread_per_s: max - min of the running estimate over the last quarter. t_s: (K,) end of each
    interval after the transient. running_per_s: (K,) the estimate up to it. stretch: (K,)
    ln(d/d0) of each interval. interval_s, dt_s, transient_s: the settings. x_end: (4,) the
    final state."""

    exponent_per_s: float
    spread_per_s: float
    t_s: NDArray[np.float64]
    running_per_s: NDArray[np.float64]
    stretch: NDArray[np.float64]
    interval_s: float
    dt_s: float
    transient_s: float
    x_end: NDArray[np.float64]


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
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
) -> Lyapunov:
    """The largest Lyapunov exponent (module docstring).

    Args:
      params: rig parameters. drive: any drive (or None: the free rig).
      x0: (4,) initial state. duration_s: time over which exponents are averaged, after
        transient_s of settling. interval_s: time between renormalisations (a whole number of
        steps of dt_s; for a periodic drive, its period is a good choice).
      d0: separation of the companion (scaled norm). omega_ref_rad_s: rates are divided by it
        in the norm. seed: the companion's initial direction (np.random.default_rng(seed)).
      progress: called with the simulated seconds of each interval.
    """
    for name, value in (("duration_s", duration_s), ("interval_s", interval_s), ("dt_s", dt_s), ("d0", d0)):
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{name} must be > 0, got {value}")
    if not (math.isfinite(transient_s) and transient_s >= 0):
        raise ParameterError(f"transient_s must be >= 0, got {transient_s}")
    n_int = round(interval_s / dt_s)
    if n_int < 1 or abs(n_int * dt_s - interval_s) > 1e-9 * interval_s:
        raise ParameterError(f"interval_s = {interval_s} s must be a whole number of steps of dt_s = {dt_s} s")
    k_total = max(1, round(duration_s / interval_s))
    n_transient = round(transient_s / dt_s)
    targets = drive.targets if drive is not None else ()
    x = np.asarray(x0, dtype=float).reshape(1, 4)
    weights = np.array([1.0, 1.0, 1.0 / omega_ref_rad_s, 1.0 / omega_ref_rad_s])
    rng = np.random.default_rng(seed)
    direction = rng.standard_normal(4)
    direction /= np.linalg.norm(direction)
    with RigFlow(params, targets) as flow:
        t = 0.0
        chunk = max(n_int, 1000)
        done = 0
        while done < n_transient:
            k = min(chunk, n_transient - done)
            u = held_inputs(drive, k, dt_s, t0_s=t)[None]
            x = flow.run(x, dt_s, k, u)[:, -1]
            done += k
            t = done * dt_s
            if progress is not None:
                progress(k * dt_s)
        pair = np.vstack([x, x + d0 * direction / weights])
        stretch = np.empty(k_total)
        for j in range(k_total):
            u = held_inputs(drive, n_int, dt_s, t0_s=t)[None]
            pair = flow.run(pair, dt_s, n_int, u)[:, -1]
            t += n_int * dt_s
            sep = pair[1] - pair[0]
            d = float(scaled_norm(sep, omega_ref_rad_s))
            if not (d > 0 and math.isfinite(d)):
                raise ParameterError("the companion run coincided with the run; raise d0")
            stretch[j] = math.log(d / d0)
            pair[1] = pair[0] + sep * (d0 / d)
            if progress is not None:
                progress(n_int * dt_s)
    times = np.asarray((np.arange(k_total) + 1) * n_int * dt_s, dtype=np.float64)
    total = np.cumsum(stretch)
    running = total / times
    tail = running[int(0.75 * k_total) :]
    half = slice(k_total // 2, k_total)
    slope = float(np.polyfit(times[half], total[half], 1)[0]) if k_total >= 4 else float(running[-1])
    return Lyapunov(
        exponent_per_s=slope,
        spread_per_s=float(np.max(tail) - np.min(tail)),
        t_s=times,
        running_per_s=running,
        stretch=stretch,
        interval_s=n_int * dt_s,
        dt_s=dt_s,
        transient_s=n_transient * dt_s,
        x_end=pair[0].copy(),
    )
