"""Pseudo-arclength continuation of the solutions of G(u) = 0, G: R^(n+1) -> R^n.

A generic predictor-corrector (Keller): from a solution u_k with unit tangent t_k (in scaled
coordinates z = u / scale) predict z = z_k + ds t_k, then correct by Newton on

    G(u) = 0,   t_k . (z - z_k) - ds = 0,

with the full Jacobian each iteration (the analyses get it from one batched rollout together with
the residual). The new tangent is the null vector of dG/dz, oriented like the previous one. The
step grows after an easy correction and halves after a failed one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError, SimulationDiverged

# G(u) -> (residual (n,), Jacobian (n, n + 1) with respect to u, extra data kept with the point)
System = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64], Any]]


@dataclasses.dataclass(frozen=True)
class Settings:
    """Step control: arclength steps in scaled coordinates; Newton tolerance on |G| (in G's
    units) and on the scaled correction."""

    ds: float = 0.02
    ds_min: float = 1e-5
    ds_max: float = 0.05
    max_points: int = 400
    newton_tol: float = 1e-10
    step_tol: float = 1e-9
    max_newton: int = 8
    easy_newton: int = 3


@dataclasses.dataclass(frozen=True)
class Point:
    """One converged solution: u, the unit tangent in scaled coordinates, the residual norm, the
    Newton iterations it took and the system's extra data."""

    u: NDArray[np.float64]
    tangent: NDArray[np.float64]
    residual: float
    iterations: int
    extra: Any


def null_vector(jac_scaled: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit vector spanning the null space of an (n, n + 1) matrix of rank n."""
    _, _, vt = np.linalg.svd(jac_scaled)
    return vt[-1]


def newton(
    system: System,
    u0: NDArray[np.float64],
    *,
    scale: NDArray[np.float64],
    fixed: int | None = None,
    tangent: NDArray[np.float64] | None = None,
    anchor: NDArray[np.float64] | None = None,
    ds: float = 0.0,
    tol: float = 1e-10,
    step_tol: float = 1e-9,
    max_iter: int = 8,
) -> Point:
    """Correct u0 onto G(u) = 0 with one more condition: the component ``fixed`` of u held (a
    natural parameter), or the pseudo-arclength condition tangent . (z - anchor) = ds.

    Raises:
      ParameterError: Newton did not converge within max_iter (the message says how close).
    """
    u = np.array(u0, dtype=float)
    res_norm = np.inf
    it = 0
    while it < max_iter:
        it += 1
        g, jac, extra = system(u)
        res_norm = float(np.max(np.abs(g)))
        jz = jac * scale  # d G / d z
        if fixed is not None:
            row = np.zeros(len(u))
            row[fixed] = 1.0
            rhs_extra = 0.0
        else:
            assert tangent is not None and anchor is not None
            row = tangent
            rhs_extra = float(tangent @ (u / scale - anchor) - ds)
        a = np.vstack([jz, row])
        rhs = -np.concatenate([g, [rhs_extra]])
        try:
            dz = np.linalg.solve(a, rhs)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(dz)):
            break
        u = u + dz * scale
        if res_norm < tol and np.max(np.abs(dz)) < step_tol:
            jz_new = jz
            t = null_vector(jz_new)
            if tangent is not None and t @ tangent < 0:
                t = -t
            return Point(u - dz * scale, t, res_norm, it, extra)
        if np.max(np.abs(dz)) < step_tol:  # the correction is negligible: evaluate once more
            continue
    raise ParameterError(f"Newton did not converge (residual {res_norm:.2e} after {max_iter} iterations)")


def continue_branch(
    system: System,
    start: Point,
    *,
    scale: NDArray[np.float64],
    settings: Settings = Settings(),
    stop: Callable[[Point], bool] = lambda p: False,
    progress: Callable[[Point], None] | None = None,
) -> tuple[list[Point], str]:
    """Follow the branch through ``start`` along its tangent until ``stop(point)`` is true (the
    stopping point is kept), max_points, or the step falls below ds_min.

    Returns:
      (points, why it ended: "stop", "max_points" or "step too small").
    """
    points = [start]
    ds = settings.ds
    while len(points) < settings.max_points:
        last = points[-1]
        z_last = last.u / scale
        predicted = (z_last + ds * last.tangent) * scale
        try:
            p = newton(
                system,
                predicted,
                scale=scale,
                tangent=last.tangent,
                anchor=z_last,
                ds=ds,
                tol=settings.newton_tol,
                step_tol=settings.step_tol,
                max_iter=settings.max_newton,
            )
        except (ParameterError, SimulationDiverged):
            ds /= 2
            if ds < settings.ds_min:
                return points, "step too small"
            continue
        points.append(p)
        if progress is not None:
            progress(p)
        if stop(p):
            return points, "stop"
        if p.iterations <= settings.easy_newton:
            ds = min(settings.ds_max, ds * 1.5)
        elif p.iterations >= settings.max_newton - 1:
            ds = max(settings.ds_min, ds / 1.5)
    return points, "max_points"


@dataclasses.dataclass(frozen=True)
class TurningPoint:
    """Where a branch turns back in one component of u, refined (``turning_point``).

    point: the converged solution there. bracket: the two converged solutions either side of it
    on the last bracket (the turning point lies between them on the branch). iterations: solves.
    """

    point: Point
    bracket: tuple[Point, Point]
    iterations: int


def turning_point(
    system: System,
    before: Point,
    after: Point,
    *,
    scale: NDArray[np.float64],
    component: int,
    settings: Settings = Settings(),
    arclength_tol: float = 1e-7,
    max_iter: int = 40,
) -> TurningPoint:
    """The turning point of u[component] between two consecutive points of a branch, whose
    tangents' components have opposite signs: the root of the tangent's component over the
    pseudo-arclength s from ``before`` (the solution on the hyperplane t . (z - z_before) = s,
    t = before's tangent), by regula falsi with the Illinois modification, until the bracket in s
    is below ``arclength_tol`` (scaled units).

    Raises:
      ParameterError: the tangents do not change sign, or a correction did not converge.
    """
    z0, t0 = before.u / scale, before.tangent
    lo, hi = (0.0, before), (float(t0 @ (after.u / scale - z0)), after)
    h_lo, h_hi = float(before.tangent[component]), float(after.tangent[component])
    if not h_lo * h_hi < 0 or not hi[0] > 0:
        raise ParameterError("no turning point between these points: the tangent's component keeps its sign")
    side = 0
    it = 0
    while it < max_iter:
        it += 1
        if hi[0] - lo[0] <= arclength_tol:
            break
        s = hi[0] - h_hi * (hi[0] - lo[0]) / (h_hi - h_lo)
        s = min(max(s, lo[0] + 0.01 * (hi[0] - lo[0])), hi[0] - 0.01 * (hi[0] - lo[0]))
        share = (s - lo[0]) / (hi[0] - lo[0])
        guess = lo[1].u + share * (hi[1].u - lo[1].u)
        p = newton(system, guess, scale=scale, tangent=t0, anchor=z0, ds=s, tol=settings.newton_tol,
                   step_tol=settings.step_tol, max_iter=settings.max_newton)  # fmt: skip
        h = float(p.tangent[component])
        if h * h_lo > 0:
            lo, h_lo = (s, p), h
            h_hi = h_hi / 2 if side == -1 else h_hi  # Illinois: the same end kept twice
            side = -1
        else:
            hi, h_hi = (s, p), h
            h_lo = h_lo / 2 if side == 1 else h_lo
            side = 1
    best = min((lo[1], hi[1]), key=lambda q: abs(float(q.tangent[component])))
    return TurningPoint(point=best, bracket=(lo[1], hi[1]), iterations=it)
